"""Where a batched IK solve spends its time: the sweep loop against the work around it.

Setup as ``ik_throughput.py``: a 6-joint unit chain, 100,000 random float32 targets,
``max_iters=10``, ``tol=0``.  For FABRIK and CCD it records the fusion count of the
optimised HLO (whole program and loop body), then runs the warm solve under
``jax.profiler`` and sums the time of the XLA ops that run once per sweep (the loop) and
once per solve (setup before the loop, the rotation rebuild, FK and the output layout
after it).  The profiler's own overhead inflates both sums; compare them with each
other, and the wall time with ``ik_throughput.py``.

Run: ``python benchmarks/ik_profile.py [--n 100000]``; writes
``benchmarks/results/ik_profile.json``.
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import os
import re
import sys
import tempfile

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import time_call, write  # noqa: E402
from ik_throughput import random_targets  # noqa: E402

from jaxsim import ik  # noqa: E402

RUNS = 5


def loop_body_fusions(hlo: str) -> int:
    """Fusions in the largest while-loop body of an optimised HLO text."""
    best = 0
    for comp in re.split(r"\n(?=\S)", hlo):
        head = comp.split("\n", 1)[0]
        if "region" in head and "ENTRY" not in head:
            best = max(best, comp.count(" fusion("))
    return best


def profile(fn, arg, sweeps: int) -> dict:
    """Per-op times (ms per solve) from a profiler trace of ``RUNS`` warm calls."""
    with tempfile.TemporaryDirectory() as d:
        with jax.profiler.trace(d, create_perfetto_trace=True):
            for _ in range(RUNS):
                jax.block_until_ready(fn(arg))
        (path,) = glob.glob(os.path.join(d, "**", "*.trace.json.gz"), recursive=True)
        events = json.load(gzip.open(path))["traceEvents"]
    total, count = collections.defaultdict(float), collections.Counter()
    for e in events:
        name = e.get("name", "")
        if e.get("ph") != "X" or name.startswith("$") or "Thunk" in name or "Pjit" in name or "PjRt" in name:
            continue
        if name.startswith(("while", "cond")):  # containers; their ops are counted themselves
            continue
        total[name] += e["dur"] / 1e3 / RUNS
        count[name] += 1
    per_sweep = {k: v for k, v in total.items() if count[k] >= sweeps * RUNS}
    once = {k: v for k, v in total.items() if k not in per_sweep}
    top = sorted(once.items(), key=lambda kv: -kv[1])[:8]
    return {"loop_ops_ms": sum(per_sweep.values()), "once_ops_ms": sum(once.values()),
            "loop_op_kinds": len(per_sweep), "once_op_kinds": len(once),
            "top_once_ops_ms": {k: round(v, 3) for k, v in top}}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=100_000)
    args = ap.parse_args()
    chain = ik.Chain(np.asarray(ik.straight_chain(np.ones(5, np.float32), direction=(0, 1, 0)).offsets, np.float32))
    targets = jnp.asarray(random_targets(args.n, 5.0, np.random.default_rng(0)))
    out = {}
    for solver in ("fabrik", "ccd"):
        fn = jax.jit(lambda t, solver=solver: ik.solve(chain, t[:, None], solver=solver, max_iters=10, tol=0.0))
        timing = time_call(fn, targets)
        hlo = fn.lower(targets).compile().as_text()
        row = {"solves_per_s": args.n / timing["run_s"], **timing, "hlo_fusions": hlo.count(" fusion("),
               "loop_body_fusions": loop_body_fusions(hlo), **profile(fn, targets, 10)}
        out[solver] = row
        print(f"{solver}: {row['solves_per_s'] / 1e6:.3f} M solves/s; fusions {row['hlo_fusions']} "
              f"({row['loop_body_fusions']} per sweep); profiled loop ops {row['loop_ops_ms']:.1f} ms, "
              f"once {row['once_ops_ms']:.1f} ms; top once: {row['top_once_ops_ms']}", flush=True)
    write("ik_profile", {"n_targets": args.n, "chain": "6 joints, unit bones", "dtype": "float32",
                         "max_iters": 10, "tol": 0.0, "profile_runs": RUNS, "solvers": out})


if __name__ == "__main__":
    main()
