"""float32 against float64 implicit Euler: does the cloth move the same, and does
``converged`` say so when it does not?

The lab cloth from rest, default ``ImplicitEuler()``: mean drop of the particles after
0.1 s at dt = 1/60, 1e-3 and 1/6000, and after 0.5 s at dt = 1/60 with k = 1e11 and 1e12.
Reports the relative drop error of float32, the share of steps flagged converged, the mean
Newton iterations and the largest relative gradient.

Run: ``python benchmarks/cloth_precision.py``; writes ``benchmarks/results/cloth_precision.json``.
"""

from __future__ import annotations

import os
import sys

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import write  # noqa: E402

from jaxsim import cloth as C  # noqa: E402

CASES = [("dt=1/60", 1 / 60, 6, None), ("dt=1e-3", 1e-3, 100, None), ("dt=1/6000", 1 / 6000, 600, None),
         ("k=1e11", 1 / 60, 30, 1e11), ("k=1e12", 1 / 60, 30, 1e12)]


def run(dtype, dt, n, k):
    c = C.lab_cloth(dtype=dtype)
    if k is not None:
        c = C.replace(c, stiffness=k)
    states, infos = C.rollout(c, C.State.at_rest(c), dt, n)
    drop = float(np.mean(np.asarray(c.rest[:, 1], np.float64) - np.asarray(states.x[-1, :, 1], np.float64)))
    return {"drop_m": drop, "converged_share": float(np.mean(infos.converged)),
            "newton_mean": float(np.mean(infos.newton_iters)), "rel_grad_max": float(np.max(infos.rel_grad)),
            "stable": bool(np.all(infos.stable))}


def main() -> None:
    rows = []
    for name, dt, n, k in CASES:
        r64, r32 = run(np.float64, dt, n, k), run(np.float32, dt, n, k)
        err = abs(r32["drop_m"] - r64["drop_m"]) / r64["drop_m"]
        rows.append({"case": name, "dt": dt, "steps": n, "stiffness": k, "float64": r64, "float32": r32,
                     "float32_drop_rel_error": err,
                     "honest": bool(err <= 0.02 or r32["converged_share"] < 0.1)})
        print(f"{name:10s} drop f64 {r64['drop_m']:.5e} f32 {r32['drop_m']:.5e} (error {100 * err:.2f}%), "
              f"converged f64 {100 * r64['converged_share']:.0f}% f32 {100 * r32['converged_share']:.0f}%", flush=True)
    write("cloth_precision", {"scene": "lab cloth from rest, ImplicitEuler()", "rows": rows})


if __name__ == "__main__":
    main()
