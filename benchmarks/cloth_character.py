"""Cloth on a moving character: a cape on the CMU walk, with the wind on and off.

A ``n x n``-particle cape (0.42 x 0.62 m, 0.25 kg/m^2, k = 300 N/m), its top row fixed in
the chest's frame (``anim.bone_points``) of ``anim.cmu_walk`` from 4 s for ``--seconds``,
colliding with eleven body capsules along the bones (``anim.body_capsules``), at
dt = 1/60 with the default ``ImplicitEuler()`` (``jaxsim._cli.demo_cape.cape``).  The same
scene with a light wind (0.5 m/s against the walk, drag 0.3, lift 0.1) and without,
alternated in one process (warm rollouts, compile apart): ms per step, the share of steps
converged, substeps, Newton iterations, the least signed distance of any particle to the
body over the returned states, and how far the pinned particles are from their path.

Run: ``python benchmarks/cloth_character.py [--quick] [--n 24] [--seconds 4] [--dtypes float32,float64]``;
writes ``benchmarks/results/cloth_character.json`` (``--quick``: a 12x12 cape over 1 s,
``cloth_character_quick.json``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import write  # noqa: E402

from jaxsim._cli.demo_cape import CMU_BODY, cape, min_distance  # noqa: E402
from jaxsim import cloth as C  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="a 12x12 cape over 1 s")
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--dtypes", default="float32")
    a = ap.parse_args()
    n, seconds = (12, 1.0) if a.quick else (a.n, a.seconds)
    rows = []
    for dtype in [np.dtype(d) for d in a.dtypes.split(",")]:
        cases = {}
        for wind in (True, False):
            c = cape(n, seconds, drag=0.3 if wind else 0.0, lift=0.1 if wind else 0.0, dtype=dtype)
            f = jax.jit(lambda s, c=c: C.rollout(c.scene, s, c.dt, c.steps, colliders=c.colliders, pins=c.pins))
            t0 = time.perf_counter()
            out = jax.block_until_ready(f(c.state))
            cases[wind] = {"cape": c, "f": f, "first_s": time.perf_counter() - t0, "runs": [], "out": out}
            print(f"{dtype.name} wind {wind}: first call {cases[wind]['first_s']:.1f} s", flush=True)
        for _ in range(a.rounds):  # alternated warm runs
            for wind in (True, False):
                k = cases[wind]
                t0 = time.perf_counter()
                jax.block_until_ready(k["f"](k["cape"].state))
                k["runs"].append(time.perf_counter() - t0)
        for wind in (True, False):
            k = cases[wind]
            c, (states, info) = k["cape"], k["out"]
            run = float(np.median(k["runs"]))
            row = {"n": n, "particles": c.scene.num_particles, "dtype": dtype.name, "wind": wind,
                   "seconds": seconds, "steps": c.steps, "capsules": len(CMU_BODY),
                   "ms_per_step": 1e3 * run / c.steps, "compile_s": max(k["first_s"] - run, 0.0),
                   "converged_share": float(np.mean(info.converged)), "stable": bool(np.all(info.stable)),
                   "substeps_max": int(np.max(info.substeps)), "substeps_mean": float(np.mean(info.substeps)),
                   "newton_per_step": float(np.mean(info.newton_iters)),
                   "min_distance_to_body_m": min_distance(c, states),
                   "max_pin_error_m": float(np.abs(np.asarray(states.x)[:, :n] - np.asarray(c.pins)).max())}
            rows.append(row)
            print(row, flush=True)
    name = "cloth_character" + ("_quick" if a.quick else "")
    write(name, {"rows": rows, "dt": 1 / 60, "quick": bool(a.quick), "rounds": a.rounds})


if __name__ == "__main__":
    main()
