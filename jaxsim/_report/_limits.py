"""IK section of the report: CCD, FABRIK and LM on the humanoid with joint limits."""

from __future__ import annotations

import numpy as np

from .. import ik
from ._doc import Doc, fig_axes
from ._humanoid import SETTINGS, error_curves, label_error_axes, random_poses, timed

SOLVERS = ("ccd", "fabrik", "lm")
COLORS = {"ccd": "C3", "fabrik": "C0", "lm": "C2"}


def limits_section(doc: Doc) -> None:
    from .._jobs.scenes import humanoid_targets

    doc.progress("IK 6: CCD, FABRIK and LM with joint limits")
    H = ik.humanoid(np.float64)
    eff = tuple(H.index(n) for n in ik.HUMANOID_EFFECTORS)
    n, M, tol = (8, 40, 1e-4) if doc.quick else (300, 100, 1e-4)
    R = ik.project_limits(H, random_poses(np.random.default_rng(5), (n, H.num_joints)))
    T = np.asarray(ik.fk(H, R).positions)[:, eff]
    fig, axes = fig_axes(2, 1, w=4.6, h=3.4)
    rows = []
    for s in SOLVERS:
        res, secs, compile_s = timed(lambda s=s: ik.solve(H, T, solver=SETTINGS[s](M, tol, trace=True),
                                                           effectors=eff))
        tr, it, conv = np.asarray(res.trace), np.asarray(res.iterations), np.asarray(res.converged)
        per_it = secs / M / n
        error_curves(axes, tr, per_it, COLORS[s], s)
        rows.append({"solver": s, "conv": 100.0 * conv.mean(), "iters": float(it[conv].mean()) if conv.any() else "",
                     "median": float(np.median(np.asarray(res.error).max(-1))), "us": 1e6 * per_it,
                     "viol": float(np.max(np.asarray(ik.limit_violation(H, res.rotations)))), "compile": compile_s})
    label_error_axes(fig, axes, tol, "sweep (LM: iteration)")
    doc.md("## IK 6. CCD, FABRIK and LM with joint limits",
           f"`ik.humanoid()` with its documented limits (elbows and knees hinges of 0–150°, swing-twist cones "
           f"elsewhere, hands and toes fixed), hands and ankles as effectors; {n} target sets made by FK of random "
           "poses projected onto the limits (so every set is reachable within them), solved from each solver's "
           f"default start (the rest pose; for LM with every hinge at mid-range) in float64, tol {tol:g}, at most {M} "
           "sweeps or LM iterations.  CCD turns each hinge by its best angle about the axis and projects other "
           "joints' rotations onto their limits; FABRIK projects each joint's rotation in its forward pass and turns "
           "a hinge's parent so the hinge plane holds the bend; LM (damped least squares with the geometric "
           "Jacobian from one FK pass) projects each trial pose, holding a hinge on a bound that steepest descent "
           "would push out of range.")
    doc.figure(fig, "ik_limits.png", "Humanoid with joint limits: worst effector error against iterations and time")
    doc.table("ik_limits", rows, {"solver": "solver", "conv": f"converged in {M} %", "iters": "mean iterations "
                                  "(converged)", "median": "median worst error (m)", "us": "µs per iteration per set",
                                  "viol": "max limit violation (rad)", "compile": "compile (s)"},
              {"conv": ".1f", "iters": ".1f", "median": ".2e", "us": ".2f", "viol": ".1e", "compile": ".1f"})
    if doc.quick:  # the tracks compile six more programs of the humanoid (minutes): full runs only
        doc.md("Jitter along the lab's curves with limits off and on: computed in full runs only.")
        return
    # jitter along the lab's curves, limits off and on
    targets = humanoid_targets(H)
    jrows = []
    for lim in (False, True):
        sk = H if lim else ik.humanoid(np.float64, limits=False)
        for s in SOLVERS:
            res = ik.track(sk, targets, solver=s, effectors=eff, max_iters=M, tol=tol)
            jit = np.asarray(ik.jitter(res.rotations))
            jrows.append({"limits": "on" if lim else "off", "solver": s, "conv": 100 * float(np.mean(res.converged)),
                          "mean": float(np.degrees(jit.mean())), "max": float(np.degrees(jit.max())),
                          "viol": float(np.max(np.asarray(ik.limit_violation(H, res.rotations))))})
    doc.md(f"Jitter along the lab's curves: the hands trace the circle and the heart ({len(targets)} frames, "
           "feet planted), each frame warm-started from the last (`ik.track`); jitter is the largest joint rotation "
           "change between frames.  The violation column measures the free skeleton's poses against the limits too.")
    doc.table("ik_limits_jitter", jrows, {"limits": "limits", "solver": "solver", "conv": "frames converged %",
                                          "mean": "mean jitter (°)", "max": "max jitter (°)",
                                          "viol": "max limit violation (rad)"},
              {"conv": ".1f", "mean": ".2f", "max": ".2f", "viol": ".1e"})
