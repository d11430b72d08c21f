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


def run(names: list[str]) -> int:
    d = bench_dir()
    if d is None:
        raise CLIError("the benchmark scripts are not installed: they ship with the source checkout; "
                       "install it with `pip install -e .` and run from there")
    scripts = sorted(f[:-3] for f in os.listdir(d) if f.endswith(".py") and not f.startswith("_"))
    chosen = names or scripts
    unknown = [n for n in chosen if n not in scripts]
    if unknown:
        raise CLIError(f"unknown benchmark(s) {unknown}; available: {scripts}")
    rc = 0
    for name in chosen:
        print(f"[bench] {name}", flush=True)
        rc |= subprocess.call([sys.executable, os.path.join(d, name + ".py")])
    return rc
