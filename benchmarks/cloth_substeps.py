"""Adaptive substeps (``ImplicitEuler(max_substep_depth=...)``): do the defaults converge?

Scene C (an ``n x n`` grid 0.2 m apart, total mass 1 kg, g = 9.8, no damping, two corners
pinned, dt = 1/30) dropped from rest: 32x32 over 40 steps and 64x64 over 20, k = 1e3 and
1e5, float64 and float32.  And the drape: a square cloth of 0.5 kg, 1.2 m across, k = 1e3,
damping 0.01, dropped 0.1 m above a sphere (radius 0.35, friction 0.4) over a floor
(friction 0.4), dt = 1/60, 60 steps, 32x32 and 64x64, float64.  Every row runs the default
settings with ``max_substep_depth=0`` (no substeps) and the default 4, alternated in one
process: the share of steps converged, the substeps used, Newton iterations per step, and
ms per step of the warm rollout (compile apart).

Run: ``python benchmarks/cloth_substeps.py [--quick]``; writes
``benchmarks/results/cloth_substeps.json``.
"""

from __future__ import annotations

import argparse
import os
import sys

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import time_call, write  # noqa: E402

import jaxsim  # noqa: E402
from jaxsim import cloth as C  # noqa: E402

DEPTHS = (0, 4)


def scene_c(n, k, dtype):
    return C.grid(n - 1, 0.2, mass=1.0 / n**2, stiffness=k, gravity=9.8, damping=0.0, dtype=dtype)


def drape(n, dtype, k=1e3, friction=0.4, cloth=C):
    """The drape: 0.5 kg, 1.2 m square, onto a sphere over a floor; ``cloth``: the ``jaxsim.cloth``
    module that builds it (``cloth_ab.py`` passes a baseline revision's)."""
    C = cloth
    span = 1.2
    sphere = C.Sphere(np.array([0.0, 0.5, 0.0]), 0.35, friction=friction)
    floor = C.Plane(np.array([0.0, 1.0, 0.0]), 0.0, friction=friction)
    return C.grid(n - 1, span / (n - 1), origin=(-span / 2, 0.95, -span / 2), mass=0.5 / n**2, stiffness=k,
                  damping=0.01, gravity=9.8, pins=[], colliders=(sphere, floor), dtype=dtype)


def run(name, cloth, dt, steps, depth):
    integ = C.ImplicitEuler(max_substep_depth=depth)
    s0 = C.State.at_rest(cloth)
    f = jax.jit(lambda s: C.rollout(cloth, s, dt, steps, integ))
    t = time_call(f, s0, repeats=1)
    _, inf = f(s0)
    sub = np.asarray(inf.substeps)
    row = {"case": name, "particles": cloth.num_particles, "dtype": np.dtype(cloth.dtype).name, "steps": steps,
           "max_substep_depth": depth, "converged_share": float(np.mean(inf.converged)),
           "stable": bool(np.all(inf.stable)), "substeps_total": int(sub.sum()), "substeps_max": int(sub.max()),
           "steps_substepped": int(np.sum(sub > 1)), "newton_per_step": float(np.mean(inf.newton_iters)),
           "max_rel_grad": float(np.max(inf.rel_grad)), "ms_per_step": 1e3 * t["run_s"] / steps,
           "compile_s": t["compile_s"]}
    print(f"{name} {row['dtype']} depth {depth}: converged {100 * row['converged_share']:.1f}%, substeps "
          f"{row['substeps_total']} over {steps} steps (max {row['substeps_max']}), Newton "
          f"{row['newton_per_step']:.1f}/step, {row['ms_per_step']:.1f} ms/step, compile {row['compile_s']:.1f} s",
          flush=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="32x32 only")
    args = ap.parse_args()
    jaxsim.retain_host_memory()
    sizes = ((32, 40),) if args.quick else ((32, 40), (64, 20))
    rows = []
    for n, steps in sizes:
        for k in (1e3, 1e5):
            for dtype in (np.float64, np.float32):
                c = scene_c(n, k, dtype)
                for depth in DEPTHS:
                    rows.append(run(f"C {n}x{n} k={k:.0e}", c, 1 / 30, steps, depth))
    for n, _ in sizes:
        c = drape(n, np.float64)
        for depth in DEPTHS:
            rows.append(run(f"drape {n}x{n}", c, 1 / 60, 60, depth))
    write("cloth_substeps", {"rows": rows, "scene_c": "n x n grid 0.2 m apart, total mass 1 kg, g 9.8, no damping, "
                             "two corners pinned, dt 1/30, from rest",
                             "drape": "0.5 kg, 1.2 m square, k 1e3, damping 0.01, sphere r 0.35 at y 0.5 and floor, "
                             "friction 0.4, dt 1/60, 60 steps, from rest 0.1 m above the sphere"})


if __name__ == "__main__":
    main()
