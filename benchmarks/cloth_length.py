"""Per-step cost against rollout length: what a rollout's first steps cost, alternated in one process.

``rollout`` starts each step from an extrapolation of the velocities before it
(``ImplicitEuler.extrapolate``).  A rollout from a bare state takes those of the
backward-Euler motion that ends at it (from its forces), ``rollout(..., resume=(states,
infos))`` the previous chunk's.  A short rollout's cost per step also includes the
call's fixed cost.  This script compiles 10- and 40-step rollouts from the same state (30 steps into
the motion, default settings, float64 unless marked) and a 10-step rollout resumed from
the 10 steps before that state, and times the three in alternation, so that all see the
same machine load.  Reported: median ms per step of each, the paired ratio (40 / 10,
median over the pairs), the marginal cost of steps 11-40 ((t40 - t10) / 30, median over
the pairs: the cost per step of a long simulation), and the Newton and CG iterations of
the first two steps against the rest, bare and resumed.

Scenes: A lab cloth, B 32x32 (float64 and float32) and B 128x128 (``cloth_step``'s A and B).

Run: ``python benchmarks/cloth_length.py``; writes ``benchmarks/results/cloth_length.json``.
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
from jaxsim import cloth as C  # noqa: E402

SHORT, LONG, WARM = 10, 40, 30


def run(name, c, dt, dtype, reps):
    integ = C.ImplicitEuler(linear_solver=C.CG())
    c = jax.tree_util.tree_map(lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, c)
    w, _ = C.rollout(c, C.State.at_rest(c), dt, WARM - SHORT, integ)
    before = C.rollout(c, C.State(w.x[-1], w.v[-1]), dt, SHORT, integ)  # the chunk before s0
    s0 = C.State(before[0].x[-1], before[0].v[-1])
    fns, compile_s = {}, {}
    args = {SHORT: None, LONG: None, "resumed": before}  # each rollout's resume
    for key, n in ((SHORT, SHORT), (LONG, LONG), ("resumed", SHORT)):
        fns[key] = jax.jit(lambda s, r, n=n: C.rollout(c, s, dt, n, integ, resume=r))
        t0 = time.perf_counter()
        jax.block_until_ready(fns[key](s0, args[key]))
        compile_s[key] = time.perf_counter() - t0
    times = {key: [] for key in fns}
    for _ in range(reps):
        for key in fns:
            t0 = time.perf_counter()
            jax.block_until_ready(fns[key](s0, args[key]))
            times[key].append(time.perf_counter() - t0)
    t10, t40 = np.array(times[SHORT]), np.array(times[LONG])
    _, info = fns[LONG](s0, None)
    _, info_r = fns["resumed"](s0, before)
    newton_r = np.asarray(info_r.newton_iters)
    newton, cg = np.asarray(info.newton_iters), np.asarray(info.cg_iters)
    row = {"scene": name, "dtype": np.dtype(dtype).name, "repeats": reps,
           "ms_per_step_10": 1e3 * statistics.median(times[SHORT]) / SHORT,
           "ms_per_step_40": 1e3 * statistics.median(times[LONG]) / LONG,
           "ms_per_step_10_resumed": 1e3 * statistics.median(times["resumed"]) / SHORT,
           "paired_ratio_40_over_10": float(np.median((t40 / LONG) / (t10 / SHORT))),
           "paired_ratio_resumed_over_10": float(np.median(np.array(times["resumed"]) / t10)),
           "ms_per_step_after_10": 1e3 * float(np.median((t40 - t10) / (LONG - SHORT))),
           "compile_s_10": compile_s[SHORT], "compile_s_40": compile_s[LONG],
           "newton_resumed": newton_r.tolist(), "converged_resumed": bool(np.all(np.asarray(info_r.converged))),
           "newton_first_two": newton[:2].tolist(), "cg_first_two": cg[:2].tolist(),
           "newton_per_step_after_2": float(newton[2:].mean()), "cg_per_step_after_2": float(cg[2:].mean()),
           "converged": bool(np.all(np.asarray(info.converged)))}
    print(f"{name:10s} {row['dtype']}: {row['ms_per_step_10']:.3f} ms/step (10 steps), {row['ms_per_step_40']:.3f} (40), "
          f"steps 11-40 {row['ms_per_step_after_10']:.3f}, 10 resumed {row['ms_per_step_10_resumed']:.3f}; "
          f"Newton first two {row['newton_first_two']}, then {row['newton_per_step_after_2']:.2f}; resumed "
          f"{row['newton_resumed']}", flush=True)
    return row


def main():
    jaxsim.retain_host_memory()  # as cloth_step
    T0 = time.perf_counter()
    rows = [run("A lab", C.lab_cloth(), 1 / 60, np.float64, 60),
            run("B 32x32", C.grid(31, 0.2), 1 / 60, np.float64, 40),
            run("B 32x32", C.grid(31, 0.2), 1 / 60, np.float32, 40),
            run("B 128x128", C.grid(127, 0.2), 1 / 60, np.float64, 8)]
    write("cloth_length", {"rows": rows, "wall_s": time.perf_counter() - T0})


if __name__ == "__main__":
    main()
