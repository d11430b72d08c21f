"""Written-once spring arrays against XLA's fused recomputation, alternated in one process.

``jaxsim._fusion.materialized`` returns an array through a conditional so that XLA:CPU
writes it once instead of recomputing it inside every consumer (the spring changes,
directions, stretches and forces of ``_implicit.problem.spring_terms``, the per-spring forces
before their sums, and the preconditioner's diagonal blocks).  This script compiles the
same 10-step rollout with ``jaxsim._fusion.ENABLED`` on and off and times the two in
alternation, so that both see the same machine load: median ms per step, the paired
ratio (on / off, median over the pairs), and the Newton and CG counts, which must match.

Scenes (default settings, 30 steps into the motion): A lab cloth, B 32x32 and 128x128
(float64, and B 32x32 in float32), C 32x32 k = 1e3 and 1e5 (two-level preconditioner).

Run: ``python benchmarks/cloth_fusion.py``; writes ``benchmarks/results/cloth_fusion.json``.
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import write  # noqa: E402

import jaxsim  # noqa: E402
from jaxsim import _fusion  # noqa: E402
from jaxsim import cloth as C  # noqa: E402

T, WARM = 10, 30


def scene(name, n, k, dtype):
    if name == "A":
        c, dt, pc = C.lab_cloth(), 1 / 60, C.Jacobi()
    elif name == "B":
        c, dt, pc = C.grid(n - 1, 0.2), 1 / 60, C.Jacobi()
    else:
        c, dt, pc = C.grid(n - 1, 0.2, mass=1.0 / n**2, stiffness=k, gravity=9.8), 1 / 30, C.TwoLevel()
    w, _ = C.rollout(c, C.State.at_rest(c), dt, WARM, C.ImplicitEuler(linear_solver=C.CG(pc, tol=1e-10), tol=1e-8))
    s0 = C.State(w.x[-1].astype(dtype), w.v[-1].astype(dtype))
    c = jax.tree_util.tree_map(lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, c)
    return c, s0, dt, pc


def run(name, n, k, dtype, reps):
    c, s0, dt, pc = scene(name, n, k, dtype)
    fns, compile_s = {}, {}
    for i, on in enumerate((False, True)):
        _fusion.ENABLED = on
        # a distinct (equal-effect) setting per variant, so each is traced afresh
        integ = C.ImplicitEuler(linear_solver=C.CG(pc, max_iters=500 + i))
        f = jax.jit(lambda s, integ=integ: C.rollout(c, s, dt, T, integ))
        t0 = time.perf_counter()
        jax.block_until_ready(f(s0))
        compile_s[on] = time.perf_counter() - t0
        fns[on] = f
    _fusion.ENABLED = True
    times = {False: [], True: []}
    for _ in range(reps):
        for on in (False, True):
            t0 = time.perf_counter()
            jax.block_until_ready(fns[on](s0))
            times[on].append(time.perf_counter() - t0)
    out = {on: fns[on](s0) for on in (False, True)}
    info = {on: out[on][1] for on in (False, True)}
    row = {"scene": name, "grid": f"{n}x{n}" if n else "11x11", "stiffness": k, "dtype": np.dtype(dtype).name,
           "preconditioner": pc, "repeats": reps,
           "ms_per_step_fused": 1e3 * statistics.median(times[False]) / T,
           "ms_per_step_written_once": 1e3 * statistics.median(times[True]) / T,
           "paired_ratio": float(np.median(np.array(times[True]) / np.array(times[False]))),
           "compile_s_fused": compile_s[False], "compile_s_written_once": compile_s[True],
           "newton_per_step": float(np.mean(info[True].newton_iters)),
           "cg_per_step": float(np.mean(info[True].cg_iters)),
           "same_iterations": bool(np.array_equal(info[True].newton_iters, info[False].newton_iters)
                                   and np.array_equal(info[True].cg_iters, info[False].cg_iters)),
           "max_position_difference": float(jnp.max(jnp.abs(out[True][0].x - out[False][0].x)))}
    print(f"{name} {row['grid']} k={k:g} {row['dtype']}: {row['ms_per_step_fused']:.3f} -> "
          f"{row['ms_per_step_written_once']:.3f} ms/step (paired ratio {row['paired_ratio']:.3f}), Newton "
          f"{row['newton_per_step']:.1f}, CG {row['cg_per_step']:.1f}, same iterations {row['same_iterations']}, "
          f"max |dx| {row['max_position_difference']:.1e}", flush=True)
    return row


def main() -> None:
    jaxsim.retain_host_memory()
    rows = [run("A", 0, 0.0, np.float64, 21), run("B", 32, 0.0, np.float64, 21), run("B", 32, 0.0, np.float32, 21),
            run("B", 128, 0.0, np.float64, 9), run("C", 32, 1e3, np.float64, 7), run("C", 32, 1e5, np.float64, 5)]
    write("cloth_fusion", {"steps": T, "warm_steps": WARM, "rows": rows})


if __name__ == "__main__":
    main()
