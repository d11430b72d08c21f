"""What ``jaxsim.retain_host_memory()`` saves: page faults on compiled programs' scratch memory.

Each case runs in its own fresh process in three ways, alternating, ``ROUNDS`` times: with
glibc's default ``malloc`` ("default"), after ``jaxsim.retain_host_memory()`` ("retained"),
and with ``MALLOC_ARENA_MAX=1 MALLOC_MMAP_THRESHOLD_=1073741824
MALLOC_TRIM_THRESHOLD_=2147483647`` in the environment ("environment", ``ENV``).  The
per-call time is the median over warm calls of one jitted call (compile apart,
``block_until_ready``), and the minor page faults per call come from ``getrusage``.  The
scratch size is ``compiled.memory_analysis().temp_size_in_bytes``.

Cases: a converged cloth step (``ImplicitEuler(solver="cg")``, the default forcing) on the
lab-like grids B 64x64, 128x128 (float64 and float32) and 256x256, 30 steps into the
motion, and batched FABRIK (10 sweeps) on 100k float32 targets for a 6-joint chain.

Run: ``python benchmarks/host_memory.py``; writes ``benchmarks/results/host_memory.json``.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import write  # noqa: E402

ROUNDS = 3
CALLS = 30
CASES = ("cloth B 64x64 float64", "cloth B 128x128 float64", "cloth B 128x128 float32", "cloth B 256x256 float64",
         "fabrik 100k float32")
MODES = ("default", "retained", "environment")
ENV = {"MALLOC_ARENA_MAX": "1", "MALLOC_MMAP_THRESHOLD_": str(1 << 30), "MALLOC_TRIM_THRESHOLD_": str(2**31 - 1)}


def build(case):
    """``(jitted fn, args)`` of one case (imports jax here, in the child process)."""
    import jax

    if "float64" in case:
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from jaxsim import cloth as C
    from jaxsim import ik

    if case.startswith("cloth"):
        n = int(case.split()[2].split("x")[0])
        scene = C.grid(n - 1, 0.2, dtype=np.float64 if "float64" in case else np.float32)
        integ = C.ImplicitEuler(linear_solver=C.CG())
        warm, _ = C.rollout(scene, C.State.at_rest(scene), 1 / 60, 30, integ)
        return jax.jit(lambda s: C.step(scene, s, 1 / 60, integ)), (C.State(warm.x[-1], warm.v[-1]),)
    from ik_throughput import random_targets  # the throughput benchmark's chain and targets

    chain = ik.Chain(np.asarray(ik.straight_chain(np.ones(5, np.float32), direction=(0, 1, 0)).offsets, np.float32))
    targets = jnp.asarray(random_targets(100_000, 5.0, np.random.default_rng(0)))
    return jax.jit(lambda t: ik.solve(chain, t[:, None], solver="fabrik", max_iters=10, tol=0.0)), (targets,)


def child(case, retained):
    """Measure one case in this process; print one JSON line."""
    import resource

    import jax

    import jaxsim

    applied = jaxsim.retain_host_memory() if retained else False
    fn, args = build(case)
    temp = fn.lower(*args).compile().memory_analysis().temp_size_in_bytes
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    runs = []
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(CALLS):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        runs.append(time.perf_counter() - t0)
    faults = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / CALLS
    med = statistics.median(runs)
    print(json.dumps({"ms": 1e3 * med, "best_ms": 1e3 * min(runs), "compile_s": max(first - med, 0.0),
                      "faults_per_call": faults, "temp_mb": temp / 1e6, "applied": applied}))


def main():
    rows = []
    T0 = time.perf_counter()
    for case in CASES:
        runs = {mode: [] for mode in MODES}
        for _ in range(ROUNDS):
            for mode in MODES:
                env = {**os.environ, **ENV} if mode == "environment" else os.environ
                out = subprocess.run([sys.executable, __file__, "--child", case, str(int(mode == "retained"))],
                                     capture_output=True, text=True, check=True, env=env)
                runs[mode].append(json.loads(out.stdout.strip().splitlines()[-1]))
        row = {"case": case, "temp_mb": runs["default"][0]["temp_mb"], "applied": runs["retained"][0]["applied"]}
        for mode in MODES:
            rs = runs[mode]
            row[mode] = {"ms": statistics.median(r["ms"] for r in rs), "best_ms": min(r["best_ms"] for r in rs),
                         "faults_per_call": statistics.median(r["faults_per_call"] for r in rs),
                         "compile_s": statistics.median(r["compile_s"] for r in rs), "runs": rs}
            row[mode]["speedup"] = row["default"]["ms"] / row[mode]["ms"]
        rows.append(row)
        print(f"{case:26s} scratch {row['temp_mb']:6.1f} MB  " + "  ".join(
            f"{mode} {row[mode]['ms']:8.2f} ms ({row[mode]['faults_per_call']:6.0f} faults, x{row[mode]['speedup']:.2f})"
            for mode in MODES) + f"  [{time.perf_counter() - T0:.0f} s]", flush=True)
    write("host_memory", {"rounds": ROUNDS, "calls": CALLS, "environment": ENV, "rows": rows, "wall_s": time.perf_counter() - T0})


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--child":
        child(sys.argv[2], sys.argv[3] == "1")
    else:
        main()
