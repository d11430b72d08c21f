"""Newton on stiff, light cloth (scene C): projections and preconditioners.

Scene C: a 32x32 grid of total mass 1 (spacing 0.2, g = 9.8, dt = 1/30), k = 1e3 and 1e5,
20 steps from rest with CG, float64 and float32.  ``project_psd="auto"`` (the default:
exact Hessian, projected only where it is not positive definite) against ``True`` (every
compression eigenvalue clamped, the lab's choice), each with the block-Jacobi
preconditioner; and the default projection with the two-level preconditioner
(``_implicit.coarse``), also on a 64x64 grid (float64).  Every row uses the default forcing
term ``cg_forcing=1e-2``; the ``forcing`` rows compare it with a fixed CG tolerance
(``cg_forcing=0``) on scene B 32x32 and C 32x32.  Reports Newton and CG iterations per
step and the share of steps converged (``StepInfo.converged``: the gradient test); ms per
step is the 20-step rollout's warm wall time over 20 (compile apart; a shared machine).

Run: ``python benchmarks/cloth_stiff.py``; writes ``benchmarks/results/cloth_stiff.json``.
"""

from __future__ import annotations

import os
import sys

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import time_call, write  # noqa: E402

import jaxsim  # noqa: E402
from jaxsim import cloth as C  # noqa: E402

N, STEPS = 32, 20


def run(n, k, dtype, projection, preconditioner, forcing=1e-2, scene="C"):
    if scene == "C":
        c = C.grid(n - 1, 0.2, mass=1.0 / n**2, stiffness=k, gravity=9.8, dtype=dtype)
        dt = 1 / 30
    else:  # B: 1 kg per particle, g = 0.3, dt = 1/60
        c = C.grid(n - 1, 0.2, stiffness=k, dtype=dtype)
        dt = 1 / 60
    s0 = C.State.at_rest(c)
    pre = C.TwoLevel() if preconditioner == "two_level" else C.Jacobi()
    integ = C.ImplicitEuler(linear_solver=C.CG(pre, forcing=forcing), project_psd=projection)
    f = jax.jit(lambda s: C.rollout(c, s, dt, STEPS, integ))
    t = time_call(f, s0, repeats=1)
    _, inf = f(s0)
    row = {"scene": scene, "grid": f"{n}x{n}", "stiffness": k, "cg_forcing": forcing, "dtype": np.dtype(dtype).name, "project_psd": projection,
           "preconditioner": preconditioner,
           "ms_per_step": 1e3 * t["run_s"] / STEPS, "compile_s": t["compile_s"],
           "newton_mean": float(np.mean(inf.newton_iters)), "newton_max": int(np.max(inf.newton_iters)),
           "cg_per_step": float(np.mean(inf.cg_iters)), "converged_share": float(np.mean(inf.converged)),
           "stable": bool(np.all(inf.stable))}
    print(f"{scene} {n}x{n} k={k:.0e} {row['dtype']} project_psd={projection!s:5s} {preconditioner:9s} forcing {forcing:g}: Newton "
          f"{row['newton_mean']:.1f} (max {row['newton_max']}), CG {row['cg_per_step']:.0f}/step, converged "
          f"{100 * row['converged_share']:.0f}%, {row['ms_per_step']:.1f} ms/step", flush=True)
    return row


def main() -> None:
    jaxsim.retain_host_memory()  # benchmarks/host_memory.py: what this changes
    rows = []
    for k in (1e3, 1e5):
        for dtype in (np.float64, np.float32):
            for projection, preconditioner in (("auto", "two_level"), ("auto", "jacobi"), (True, "jacobi")):
                rows.append(run(N, k, dtype, projection, preconditioner))
    for k in (1e3, 1e5):
        rows.append(run(2 * N, k, np.float64, "auto", "two_level"))
    # the forcing term against a fixed CG tolerance, same run
    forcing = []
    for scene, k, pc in (("B", 100.0, "jacobi"), ("C", 1e3, "jacobi"), ("C", 1e3, "two_level"), ("C", 1e5, "two_level")):
        for f in (1e-2, 0.0):
            forcing.append(run(N, k, np.float64, "auto", pc, forcing=f, scene=scene))
    write("cloth_stiff", {"scene": f"C {N}x{N} (and {2 * N}x{2 * N}), total mass 1, g 9.8, dt 1/30, {STEPS} steps from rest, CG",
                         "rows": rows, "forcing": forcing})


if __name__ == "__main__":
    main()
