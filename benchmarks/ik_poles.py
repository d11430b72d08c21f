"""LM with pole targets on the limited humanoid: converged share, sets/s and compile time,
with and without poles on the same sets, alternated in one process.

1,000 float32 target sets for both hands and ankles, made by FK of random poses projected
onto the limits (as ``ik_throughput.py --only-limits``); each elbow's and knee's pole is the
true pose's middle joint pushed 0.3 m out from its limb's root-end line, so every set has a
solution that meets its poles.  tol 1e-4 (positions, and each pole's residual with poles),
at most 100 iterations, early exit; with poles also ``seeds=8``.  Also: the share of converged sets whose four limbs lie
within 1e-4 m of their poles' half-planes, measured in numpy.

Run: ``python benchmarks/ik_poles.py [--sets N] [--rounds R]``; writes ``benchmarks/results/ik_poles.json``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import write  # noqa: E402
from ik_throughput import random_poses  # noqa: E402

from jaxsim import ik  # noqa: E402

LIMBS = {"l_elbow": ("l_shoulder", "l_hand"), "r_elbow": ("r_shoulder", "r_hand"),
         "l_knee": ("l_hip", "l_ankle"), "r_knee": ("r_hip", "r_ankle")}


def half_plane_gap(a, m, e, p):
    """``(n,)`` distance (m) of ``m`` from the half-plane of the line ``a``-``e`` and ``p`` (numpy)."""
    u = (e - a) / np.linalg.norm(e - a, axis=-1, keepdims=True)

    def across(x):
        return x - np.sum(x * u, -1, keepdims=True) * u

    mp, pp = across(m - a), across(p - a)
    pn = pp / np.linalg.norm(pp, axis=-1, keepdims=True)
    return np.linalg.norm(mp - np.linalg.norm(mp, axis=-1, keepdims=True) * pn, axis=-1)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sets", type=int, default=1000)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    H = ik.humanoid(np.float32)
    eff = tuple(H.index(k) for k in ik.HUMANOID_EFFECTORS)
    R = ik.project_limits(H, random_poses(np.random.default_rng(2), (args.sets, H.num_joints)))
    P = np.asarray(ik.fk(H, R).positions, np.float64)
    T = jnp.asarray(P[:, eff], jnp.float32)
    poles = {}
    for m, (a, e) in LIMBS.items():
        pa, pm, pe = P[:, H.index(a)], P[:, H.index(m)], P[:, H.index(e)]
        u = (pe - pa) / np.linalg.norm(pe - pa, axis=-1, keepdims=True)
        out = (pm - pa) - np.sum((pm - pa) * u, -1, keepdims=True) * u
        n = np.linalg.norm(out, axis=-1, keepdims=True)
        poles[m] = jnp.asarray(pm + 0.3 * out / np.maximum(n, 1e-9), jnp.float32)
    lm, lm8 = ik.LevenbergMarquardt(100, 1e-4), ik.LevenbergMarquardt(100, 1e-4, seeds=8)
    fns = {"without poles": jax.jit(lambda t: ik.solve(H, t, solver=lm, effectors=eff)),
           "with poles": jax.jit(lambda t, p: ik.solve(H, t, solver=lm, effectors=eff, poles=p)),
           "with poles, seeds=8": jax.jit(lambda t, p: ik.solve(H, t, solver=lm8, effectors=eff,
                                                                poles=p))}
    call = {"without poles": lambda: fns["without poles"](T), "with poles": lambda: fns["with poles"](T, poles),
            "with poles, seeds=8": lambda: fns["with poles, seeds=8"](T, poles)}
    rows = {}
    for name, f in call.items():
        t0 = time.perf_counter()
        res = jax.block_until_ready(f())
        rows[name] = {"first_s": time.perf_counter() - t0, "runs": []}
        conv = np.asarray(res.converged)
        Pr = np.asarray(res.positions, np.float64)
        gaps = np.stack([half_plane_gap(Pr[:, H.index(a)], Pr[:, H.index(m)], Pr[:, H.index(e)], np.asarray(poles[m]))
                         for m, (a, e) in LIMBS.items()], -1).max(-1)
        rows[name].update(converged_fraction=float(conv.mean()), mean_iterations=float(np.mean(res.iterations)),
                          converged_on_pole_side_fraction=float(np.mean(gaps[conv] <= 1e-4)) if conv.any() else None,
                          max_limit_violation_rad=float(jnp.max(ik.limit_violation(H, res.rotations))))
    for _ in range(args.rounds):  # alternated
        for name, f in call.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f())
            rows[name]["runs"].append(time.perf_counter() - t0)
    for name, r in rows.items():
        r["run_s"] = statistics.median(r["runs"])
        r["compile_s"] = max(r["first_s"] - r["run_s"], 0.0)
        r["sets_per_s"] = args.sets / r["run_s"]
        print(f"{name}: {100 * r['converged_fraction']:.1f}% converged, {r['mean_iterations']:.1f} mean iterations, "
              f"{r['sets_per_s']:,.0f} sets/s, compile {r['compile_s']:.1f} s; converged on their poles' side: "
              f"{r['converged_on_pole_side_fraction']}", flush=True)
    ratio = statistics.median(b / a for a, b in zip(rows["without poles"]["runs"], rows["with poles"]["runs"]))
    write("ik_poles", {"sets": args.sets, "rounds": args.rounds, "dtype": "float32", "tol": 1e-4, "max_iters": 100,
                       "rows": rows, "paired_time_ratio_with_over_without": ratio})


if __name__ == "__main__":
    main()
