"""``python -m jaxsim bench``: run the scripts in ``benchmarks/`` (from a source checkout)."""

from __future__ import annotations

import os
import subprocess
import sys


def _bench_dir() -> str | None:
    here = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    for d in (os.path.join(os.getcwd(), "benchmarks"), os.path.join(here, "benchmarks")):
        if os.path.isdir(d):
            return d
    return None


def run(names: list[str]) -> int:
    d = _bench_dir()
    if d is None:
        print("benchmarks/ not found: run from a source checkout of jaxsim", file=sys.stderr)
        return 2
    scripts = sorted(f[:-3] for f in os.listdir(d) if f.endswith(".py") and not f.startswith("_"))
    chosen = names or scripts
    unknown = [n for n in chosen if n not in scripts]
    if unknown:
        print(f"unknown benchmark(s) {unknown}; available: {scripts}", file=sys.stderr)
        return 2
    rc = 0
    for name in chosen:
        print(f"[bench] {name}", flush=True)
        rc |= subprocess.call([sys.executable, os.path.join(d, name + ".py")])
    return rc
