"""``python -m jaxsim bench``: run the package's own benchmark scripts.

They live in ``benchmarks/`` beside the ``jaxsim`` package of a source checkout (an
editable install), never in the current directory: a folder of the same name elsewhere
is not run.
"""

from __future__ import annotations

import os
import subprocess
import sys

from ._out import CLIError

#: A file that marks the folder as jaxsim's own benchmarks.
_MARKER = "_common.py"


def bench_dir() -> str | None:
    """``benchmarks/`` next to the installed ``jaxsim`` package, if it is jaxsim's."""
    import jaxsim

    top = os.path.dirname(os.path.dirname(os.path.abspath(jaxsim.__file__)))
    d = os.path.join(top, "benchmarks")
    return d if os.path.isfile(os.path.join(d, _MARKER)) else None


def _summary(d: str, name: str) -> str:
    """The script's first docstring line and, where its results JSON records one, the
    wall time of its last full run."""
    import ast
    import json

    try:
        with open(os.path.join(d, name + ".py"), encoding="utf-8") as f:
            doc = ast.get_docstring(ast.parse(f.read())) or ""
    except (OSError, SyntaxError):
        doc = ""
    line = doc.strip().splitlines()[0] if doc.strip() else ""
    took = ""
    try:
        with open(os.path.join(d, "results", name + ".json"), encoding="utf-8") as f:
            wall = json.load(f).get("wall_s")
        if isinstance(wall, (int, float)):
            took = f"last run {wall / 60:.1f} min" if wall >= 60 else f"last run {wall:.0f} s"
    except (OSError, ValueError, AttributeError):
        pass
    return f"  {name:<18} {took:<18} {line}"


def run(names: list[str], run_all: bool = False) -> int:
    d = bench_dir()
    if d is None:
        raise CLIError("the benchmark scripts are not installed: they ship with the source checkout; "
                       "install it with `pip install -e .` and run from there")
    scripts = sorted(f[:-3] for f in os.listdir(d) if f.endswith(".py") and not f.startswith("_"))
    if not names and not run_all:
        print(f"{len(scripts)} benchmarks in {d}:")
        for name in scripts:
            print(_summary(d, name))
        print("run some with `python -m jaxsim bench NAME ...`, or every one with `python -m jaxsim bench --all`")
        return 0
    if names and run_all:
        raise CLIError("give benchmark names or --all, not both")
    chosen = names or scripts
    unknown = [n for n in chosen if n not in scripts]
    if unknown:
        raise CLIError(f"unknown benchmark(s) {unknown}; available: {scripts}")
    rc = 0
    for name in chosen:
        print(f"[bench] {name}", flush=True)
        rc |= subprocess.call([sys.executable, os.path.join(d, name + ".py")])
    return rc
