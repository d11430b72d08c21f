"""Report section: Newton iteration logs of stiff cloth (scene C), from ``ImplicitEuler(trace=True)``."""

from __future__ import annotations

import time

import jax
import numpy as np

from .. import cloth as C
from ._doc import Doc, fig_axes


def _scene_c(n: int, k: float):
    """Scene C: an ``n x n`` grid 0.2 m apart, total mass 1 kg, g = 9.8, two corners pinned."""
    return C.grid(n - 1, 0.2, mass=1.0 / n**2, stiffness=k, gravity=9.8, dtype=np.float64)


#: The per-iteration log tables' columns and formats.
LOG_COLUMNS = {"it": "iteration", "g": "g", "rel": "rel", "step": "step", "alpha": "alpha", "bt": "bt", "cg": "CG",
               "hessian": "Hessian"}
LOG_FORMATS = {"g": ".10e", "rel": ".2e", "step": ".2e", "alpha": ".3g"}


def _log_rows(info, k, names=C.HESSIANS):
    t = info.trace
    rows = []
    for i in range(int(info.newton_iters[k])):
        rows.append({"it": i + 1, "g": float(t.g[k, i]), "rel": float(t.rel[k, i]), "step": float(t.step[k, i]),
                     "alpha": float(t.alpha[k, i]), "bt": int(t.backtracks[k, i]), "cg": int(t.cg[k, i]),
                     "hessian": names[int(t.hessian[k, i])]})
    return rows


def newton_log_section(doc: Doc) -> None:
    n, k, steps = (12, 1e5, 3) if doc.quick else (32, 1e5, 6)
    dt = 1 / 30
    c = _scene_c(n, k)
    doc.md("## Cloth 6. Why Newton stalls on stiff cloth: iteration logs",
           f"Scene C ({n}x{n} grid, total mass 1 kg, k = {k:.0e} N/m, g = 9.8, dt = 1/30 s), float64, CG with the "
           f"two-level preconditioner, {steps} steps from rest, every Newton iteration logged "
           "(`ImplicitEuler(trace=True)`, `StepInfo.trace`).  With `project_psd=\"auto\"` (the default) each "
           "iteration's direction comes from the exact Hessian, or, where PCG meets negative curvature, from the "
           "exact Hessian with the inertia term doubled (**shifted**), or, where that is indefinite too, from the "
           "Hessian with every spring block clamped (**clamped**).  Once the relative gradient is below 1e-3 "
           "after an indefinite exact Hessian, Newton takes full steps to the exact Hessian's stationary point "
           "(**stationary**), up to six in a phase, kept once one lowers the relative gradient below its value "
           "where the phase began; a phase that does not returns there (its last iteration logged with step 0 "
           "and not taken).  `project_psd=True` always clamps (the lab's "
           "choice).  The cap is lifted to 100 Newton iterations here so that each setting's count is its own "
           "(the default cap is 20).")
    settings = {"auto": C.ImplicitEuler(linear_solver=C.CG(C.TwoLevel()), newton_iters=100, trace=True),
                "clamped": C.ImplicitEuler(linear_solver=C.CG(C.TwoLevel()), newton_iters=100, trace=True, project_psd=True)}
    doc.progress(f"cloth 6: scene C {n}x{n} k={k:.0e}, {steps} steps")
    t0 = time.perf_counter()
    states, info = jax.block_until_ready(C.rollout(c, C.State.at_rest(c), dt, steps, settings["auto"]))
    rows = []
    for s in range(steps):
        m = int(info.newton_iters[s])
        used = np.bincount(np.asarray(info.trace.hessian[s, :m]), minlength=len(C.HESSIANS))
        rows.append({"step": s + 1, "newton": m, "cg": int(info.cg_iters[s]), "exact": int(used[0]),
                     "shifted": int(used[1]), "clamped": int(used[2]), "stationary": int(used[3]),
                     "conv": bool(info.converged[s])})
    doc.table("cloth_newton_steps", rows, {"step": "step", "newton": "Newton", "cg": "CG", "exact": "exact",
                                          "shifted": "shifted", "clamped": "clamped", "stationary": "stationary",
                                          "conv": "converged"})
    hard = int(np.argmax(np.asarray(info.newton_iters)))
    start = C.State.at_rest(c) if hard == 0 else C.State(states.x[hard - 1], states.v[hard - 1])
    _, clamp = jax.block_until_ready(C.step(c, start, dt, settings["clamped"]))
    clamp_rows = _log_rows(jax.tree_util.tree_map(lambda a: a[None], clamp), 0, names=("clamped",))
    auto_rows = _log_rows(info, hard)
    used = {h: sum(r["hessian"] == h for r in auto_rows) for h in C.HESSIANS}
    tail = clamp_rows[-6:]
    rate = (tail[-1]["rel"] / tail[0]["rel"]) ** (1.0 / (len(tail) - 1))
    doc.md(f"Step {hard + 1}, the one with the most Newton iterations, iteration by iteration with the default "
           f"setting: `g` the incremental potential (J), `rel` the relative gradient (converged at 1e-9 in float64), "
           "`step` the lab's test `max|alpha dx| / h` (m/s), `alpha` and `bt` the line search's step and halvings, "
           "`CG` the PCG iterations (summed over the tries), `Hessian` which one gave the direction: "
           f"the exact Hessian {used['exact']} times, the shifted one {used['shifted']} times, the clamped one "
           f"{used['clamped']} times, the stationary-point step {used['stationary']} times.")
    doc.table("cloth_newton_log_auto", auto_rows, LOG_COLUMNS, LOG_FORMATS)
    last = clamp_rows[-1]
    doc.md(f"The same step with every block clamped (`project_psd=True`): {len(clamp_rows)} Newton iterations, "
           f"{int(clamp.cg_iters)} CG, final relative gradient {last['rel']:.2e} "
           f"({'converged' if bool(clamp.converged) else 'not converged'}), against {len(auto_rows)} iterations and "
           f"{int(info.cg_iters[hard])} CG with the default.  A clamped block is not the Hessian of the energy "
           "Newton minimises, so Newton on it converges linearly: over its last iterations the relative gradient "
           f"falls by a factor of {rate:.2f} per iteration, where the exact Hessian's last iterations square it.  "
           "First and last iterations:")
    shown = clamp_rows if len(clamp_rows) <= 12 else clamp_rows[:6] + clamp_rows[-6:]
    doc.table("cloth_newton_log_clamped", shown, LOG_COLUMNS, LOG_FORMATS)
    fig, ax = fig_axes()
    ax = ax[0, 0]
    for name, rs in (("auto (default)", auto_rows), ("clamped (project_psd=True)", clamp_rows)):
        ax.semilogy([r["it"] for r in rs], [r["rel"] for r in rs], marker=".", label=name)
    ax.axhline(1e-9, color="grey", lw=0.8, ls="--")
    ax.set_xlabel("Newton iteration")
    ax.set_ylabel("relative gradient")
    ax.set_title(f"scene C {n}x{n}, k = {k:.0e}, step {hard + 1}")
    ax.legend()
    fig.tight_layout()
    doc.figure(fig, "cloth_newton_log.png", f"Relative gradient per Newton iteration, scene C {n}x{n} k = {k:.0e}, "
                                            f"step {hard + 1}: the default against the clamped Hessian; dashed: rtol.")
    doc.md(f"Section wall time: {time.perf_counter() - t0:.0f} s.")
