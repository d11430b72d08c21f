"""The IK call a user writes, against the same call with each loop choice spelled out.

``ik.solve(model, T)`` with no settings now stops once the batch is done
(``early_exit=None``: the while loop, or LM's work queue, and the scan only where the call
is differentiated).  Per case, in one process and alternated round by round, the default
call, ``early_exit=False`` (the fixed-length scan, the old default) and ``early_exit=True``:
warm run time (median of rounds), sets per second, converged share, and compile time of
the first call.  Float32, reachable targets from FK of random poses (limited ones projected
onto the limits), 2-core CPU.

Run: ``python benchmarks/ik_defaults.py [--n 1000] [--rounds 5]``; writes
``benchmarks/results/ik_defaults.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import write  # noqa: E402

from jaxsim import ik  # noqa: E402
from jaxsim._report._humanoid import random_poses  # noqa: E402


def cases(n):
    rng = np.random.default_rng(0)
    arm = ik.lab_arm()
    Ta = jnp.asarray(np.asarray(ik.fk(arm, random_poses(rng, (n, arm.num_joints), 1.5)).positions)[:, -1], jnp.float32)
    H = ik.humanoid(np.float32, limits=False)
    HL = ik.humanoid(np.float32)
    eff = ik.HUMANOID_EFFECTORS
    ids = [H.index(e) for e in eff]
    Th = jnp.asarray(np.asarray(ik.fk(H, random_poses(rng, (n, 24))).positions)[:, ids], jnp.float32)
    TL = jnp.asarray(np.asarray(ik.fk(HL, ik.project_limits(HL, random_poses(rng, (n, 24)))).positions)[:, ids],
                     jnp.float32)
    return {"chain (lab arm), (N, 3) targets, FABRIK": (arm, Ta, {}, ik.FABRIK()),
            "humanoid FABRIK, 4 effectors": (H, Th, dict(effectors=eff), ik.FABRIK()),
            "limited humanoid LM, 4 effectors": (HL, TL, dict(effectors=eff), ik.LevenbergMarquardt())}


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=1000)
    p.add_argument("--rounds", type=int, default=5)
    a = p.parse_args()
    rows = []
    for name, (model, T, kw, settings) in cases(a.n).items():
        fns = {"default call": jax.jit(lambda t, m=model, kw=kw: ik.solve(m, t, **kw)),
               "early_exit=False (scan)": jax.jit(lambda t, m=model, kw=kw, s=settings: ik.solve(
                   m, t, solver=dataclasses.replace(s, early_exit=False), **kw)),
               "early_exit=True": jax.jit(lambda t, m=model, kw=kw, s=settings: ik.solve(
                   m, t, solver=dataclasses.replace(s, early_exit=True), **kw))}
        first, times, res = {}, {k: [] for k in fns}, {}
        for k, f in fns.items():
            t0 = time.perf_counter()
            res[k] = jax.block_until_ready(f(T))
            first[k] = time.perf_counter() - t0
        for _ in range(a.rounds):
            for k, f in fns.items():
                t0 = time.perf_counter()
                jax.block_until_ready(f(T))
                times[k].append(time.perf_counter() - t0)
        for k in fns:
            run = statistics.median(times[k])
            rows.append({"case": name, "call": k, "n": a.n, "run_s": run, "sets_per_s": a.n / run,
                         "compile_s": max(first[k] - run, 0.0), "converged": float(np.mean(res[k].converged)),
                         "mean_iterations": float(np.mean(res[k].iterations))})
            print(f"{name:42s} {k:24s} {a.n / run:12,.0f} sets/s  converged {rows[-1]['converged']:.3f}  "
                  f"compile {rows[-1]['compile_s']:.1f} s", flush=True)
    write("ik_defaults", {"rows": rows, "rounds": a.rounds})


if __name__ == "__main__":
    main()
