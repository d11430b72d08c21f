"""IK section of the report on a skeleton: CCD against FABRIK on the humanoid."""

from __future__ import annotations

import time

import jax
import numpy as np

from .. import ik
from ._doc import Doc, fig_axes

SOLVERS = ("ccd", "fabrik")
#: The settings object of each solver name.
SETTINGS = {"fabrik": ik.FABRIK, "ccd": ik.CCD, "lm": ik.LevenbergMarquardt}
COLORS = {"ccd": "C3", "fabrik": "C0"}


def random_poses(rng, shape, amp=np.pi):
    """Unit quaternions of random axis and an angle uniform in ``[0, amp]``."""
    ax = rng.normal(size=shape + (3,))
    ax /= np.linalg.norm(ax, axis=-1, keepdims=True)
    ang = amp * rng.uniform(size=shape + (1,))
    return np.concatenate([np.cos(ang / 2), np.sin(ang / 2) * ax], axis=-1)


def timed(f):
    """``(result, seconds of a warm run, compile seconds)`` of ``f()``."""
    t0 = time.perf_counter()
    jax.block_until_ready(f())
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = jax.block_until_ready(f())
    secs = time.perf_counter() - t0
    return res, secs, first - secs


def error_curves(axes, trace, per_iteration, color, name):
    """Median and 90th percentile of ``trace (n, M)`` against iterations (left) and time (right)."""
    steps = np.arange(1, trace.shape[1] + 1)
    for q, style in ((50, "-"), (90, "--")):
        p = np.percentile(trace, q, axis=0)
        axes[0, 0].semilogy(steps, p, style, color=color, label=f"{name} {q}th pct")
        axes[0, 1].semilogy(1e6 * per_iteration * steps, p, style, color=color, label=f"{name} {q}th pct")


def label_error_axes(fig, axes, tol, xlabel):
    for ax, xl in zip(axes[0], (xlabel, "time per solve (µs)")):
        ax.axhline(tol, color="0.6", lw=0.8)
        ax.set_xlabel(xl)
        ax.set_ylabel("worst effector error (m)")
        ax.legend(fontsize=7)
    fig.tight_layout()


def humanoid_section(doc: Doc) -> None:
    doc.progress("IK 5: the humanoid, CCD against FABRIK")
    H = ik.humanoid(np.float64, limits=False)
    eff = tuple(H.index(n) for n in ik.HUMANOID_EFFECTORS)
    n, M, tol = (100 if doc.quick else 500), 100, 1e-4
    T = np.asarray(ik.fk(H, random_poses(np.random.default_rng(4), (n, H.num_joints))).positions)[:, eff]
    fig, axes = fig_axes(2, 1, w=4.6, h=3.4)
    rows = []
    for s in SOLVERS:
        def f(s=s):
            return ik.solve(H, T, solver=SETTINGS[s](M, tol, trace=True), effectors=eff)

        res, secs, compile_s = timed(f)
        tr = np.asarray(res.trace)
        it = np.asarray(res.iterations)
        per_sweep = secs / M / n  # the scan runs max_iters sweeps (masked no-ops once an element is done)
        error_curves(axes, tr, per_sweep, COLORS[s], s)
        conv = np.asarray(res.converged)
        rows.append({"solver": s, "conv": 100.0 * conv.mean(), "sweeps": float(it[conv].mean()) if conv.any() else "",
                     "median": float(np.median(np.asarray(res.error).max(-1))), "us": 1e6 * per_sweep,
                     "compile": compile_s})
    label_error_axes(fig, axes, tol, "sweep")
    doc.md("## IK 5. The humanoid: CCD against FABRIK on a tree",
           f"`ik.humanoid(limits=False)` (24 joints) with both hands and both ankles as effectors; {n} target sets made by FK of "
           "random poses (each joint turned by an angle uniform in [0, π] about a random axis), solved from the rest "
           f"pose in float64, tol {tol:g}, at most {M} sweeps.  FABRIK places each sub-base (pelvis, chest) at the "
           "centroid of its branches' proposals and turns its child bones rigidly by Horn's rotation; CCD turns "
           "each joint by the rotation that best aligns the effectors below it with their targets (Horn's "
           "rotation, the shortest arc for one effector).  Curves are the median and the 90th percentile over the "
           "sets of the worst effector's error.")
    doc.figure(fig, "ik_humanoid.png", "Humanoid, hands and ankles: worst effector error against sweeps and time")
    doc.table("ik_humanoid", rows, {"solver": "solver", "conv": f"converged in {M} sweeps %",
                                    "sweeps": "mean sweeps (converged)", "median": "median worst error (m)",
                                    "us": "µs per sweep per set", "compile": "compile (s)"},
              {"conv": ".1f", "sweeps": ".1f", "median": ".2e", "us": ".2f", "compile": ".1f"})
    a, b = rows
    doc.md(f"FABRIK brings {b['conv']:.1f}% of the sets within tol against CCD's {a['conv']:.1f}%.  Both slow down "
           "where a limb must end almost straight (a 2-bone leg whose target is near full reach): there CCD's two "
           "joint turns pull nearly along the same line, and its error falls by a small factor per sweep.")
