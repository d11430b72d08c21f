"""Drawing IK chains and tracked trajectories (side view on the x-z target plane is not
enough for a 3D chain, so the chain is shown in the x-y plane the lab draws it in, with
targets projected the same way: ``plane`` picks the two world axes)."""

from __future__ import annotations

import numpy as np

from . import _style as st
from ._common import check_fps, check_frames, new_figure, world_limits
from ._gif import GifWriter, gif_dpi

_AXES = {"xy": (0, 1), "xz": (0, 2), "zy": (2, 1)}


def _check_plane(plane, allow_3d=False):
    if plane not in _AXES and not (allow_3d and plane == "3d"):
        raise ValueError(f"plane must be one of {sorted(_AXES) + (['3d'] if allow_3d else [])}, got {plane!r}")


def _xzy(a):
    """World ``(..., 3)`` as the 3D plot's ``(x, z, y)`` coordinate arrays (y up)."""
    a = np.asarray(a, np.float64).reshape(-1, 3)
    return a[:, 0], a[:, 2], a[:, 1]


def _proj(a, plane):
    _check_plane(plane)
    i, j = _AXES[plane]
    a = np.asarray(a, np.float64)
    return a[..., i], a[..., j]


def plot_chain(positions, target=None, ax=None, plane: str = "xz", color: str | None = None):
    """Draw one pose: bones as lines, joints as dots, the target as a cross.

    Args:
      positions: ``(J, 3)`` joint world positions (e.g. ``IKResult.positions``).
      target: optional ``(3,)`` target.
      ax: axes to draw on (a new figure when ``None``).
      plane: world axes shown, ``"xz"`` (the plane of the lab's curves), ``"xy"`` or ``"zy"``.

    Returns:
      The figure.
    """
    if ax is None:
        fig, ax = new_figure(4, 4)
    u, v = _proj(positions, plane)
    ax.plot(u, v, "-", color=st.BONE if color is None else color, lw=st.LIMB, solid_capstyle="round", label="chain")
    st.joints(ax, u, v)
    ax.plot(u[:1], v[:1], "ks", ms=6, label="root")
    if target is not None:
        tu, tv = _proj(target, plane)
        ax.plot([tu], [tv], "x", color=st.TARGET, ms=9, mew=2.5, label="target")
    ax.set_aspect("equal")
    ax.set_xlabel(f"{plane[0]} (m)")
    ax.set_ylabel(f"{plane[1]} (m)")
    return ax.figure


def _frame_axes(ax, targets, positions, plane, title):
    tu, tv = _proj(targets, plane)
    pu, pv = _proj(positions.reshape(-1, 3), plane)
    allu, allv = np.concatenate([tu, pu]), np.concatenate([tv, pv])
    pad = 0.1 * max(np.ptp(allu), np.ptp(allv), 1e-3)
    ax.set_xlim(allu.min() - pad, allu.max() + pad)
    ax.set_ylim(allv.min() - pad, allv.max() + pad)
    ax.set_aspect("equal")
    ax.set_xlabel(f"{plane[0]} (m)")
    ax.set_ylabel(f"{plane[1]} (m)")
    ax.set_title(title)


def _end_targets(targets):
    """A chain's ``(T, 1, 3)`` targets (as ``ik.track`` takes them) as ``(T, 3)``."""
    t = np.asarray(targets)
    return t[:, 0] if t.ndim == 3 and t.shape[1] == 1 else t


def plot_tracking(result, targets, plane: str = "xz", title: str = ""):
    """Still of a tracked trajectory: final pose, target path, end-effector trail, and
    the per-frame error below.

    Args:
      result: ``IKResult`` from ``jaxsim.ik.track`` on a chain (``positions (T, J, 3)``,
        ``error (T, 1)``).
      targets: ``(T, 1, 3)`` or ``(T, 3)``.

    Returns:
      The figure.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    _check_plane(plane)
    P = check_frames("result.positions", result.positions, (None, 3))
    err = np.asarray(result.error)
    err = err.max(-1) if err.ndim == 2 else err
    targets = check_frames("targets", _end_targets(targets), (3,), frames=len(P))
    fig = Figure(figsize=(5, 6.5), dpi=80)
    FigureCanvasAgg(fig)
    ax, ax2 = fig.subplots(2, 1, gridspec_kw={"height_ratios": [3, 1]})
    _frame_axes(ax, targets, P, plane, title)
    tu, tv = _proj(targets, plane)
    ax.plot(tu, tv, ":", color=st.PATH, label="target path")
    eu, ev = _proj(P[:, -1], plane)
    ax.plot(eu, ev, "-", color=st.EFFECTOR, lw=1, label="end-effector trail")
    plot_chain(P[-1], targets[-1], ax=ax, plane=plane)
    ax.legend(loc="best", fontsize=7)
    ax2.semilogy(np.arange(len(err)), np.maximum(err, 1e-16), color="C2", label="|end - target|")
    ax2.set_xlabel("frame")
    ax2.set_ylabel("error (m)")
    ax2.legend(fontsize=7)
    fig.tight_layout()
    return fig


def animate_tracking(result, targets, path: str, plane: str = "xz", fps: int = 30, stride: int = 1,
                     title: str = "", dpi: float | None = None):
    """Write a GIF of the chain tracing ``targets`` with the target path and the trail.

    Args:
      result: ``IKResult`` from ``jaxsim.ik.track`` on a chain.
      targets: ``(T, 1, 3)`` or ``(T, 3)``.
      path: output ``.gif`` path.
      plane: as for :func:`plot_chain`, or ``"3d"``: a perspective view, y up (the lab arm
        hangs from 1.7 m to the curves on the floor, which a top view foreshortens).
      fps: frames per second of the GIF.
      stride: draw every ``stride``-th frame.
      dpi: resolution; default the least that gives a short side of 480 px (``_gif``).

    Returns:
      The number of frames written.
    """
    _check_plane(plane, allow_3d=True)
    fps = check_fps(fps)
    P = check_frames("result.positions", result.positions, (None, 3))
    targets = check_frames("targets", _end_targets(targets), (3,), frames=len(P))
    if plane == "3d":
        return _animate_3d(P, targets, path, fps, stride, title, dpi)
    fig, ax = new_figure(4, 4)
    dpi = gif_dpi(fig, dpi)
    _frame_axes(ax, targets, P, plane, title)
    tu, tv = _proj(targets, plane)
    ax.plot(tu, tv, ":", color=st.PATH, label="target path")
    (trail,) = ax.plot([], [], "-", color=st.EFFECTOR, lw=1.2, label="end-effector trail")
    (bones,) = st.limbs(ax, [], [], label="chain")
    (discs,) = st.joints(ax, [], [])
    (tgt,) = ax.plot([], [], "x", color=st.TARGET, ms=9, mew=2.5, label="target")
    st.legend(ax, fontsize=6)
    fig.tight_layout()
    frames = range(0, len(P), max(1, int(stride)))
    with GifWriter(fig, path, fps, dpi) as writer:
        for t in frames:
            bones.set_data(*_proj(P[t], plane))
            discs.set_data(*_proj(P[t], plane))
            trail.set_data(*_proj(P[: t + 1, -1], plane))
            tgt.set_data(*[[c] for c in _proj(targets[t], plane)])
            writer.grab()
    return len(frames)


def _animate_3d(P, targets, path, fps, stride, title, dpi):
    """:func:`animate_tracking` in a perspective view."""
    fig, ax = new_figure(4, 4, projection="3d")
    dpi = gif_dpi(fig, dpi)
    world_limits(ax, np.concatenate([P.reshape(-1, 3), targets]))
    ax.plot(*_xzy(targets), ":", color=st.PATH, label="target path")
    (trail,) = ax.plot([], [], [], "-", color=st.EFFECTOR, lw=1.2, label="end-effector trail")
    (bones,) = st.limbs(ax, [], [], [], label="chain")
    (discs,) = st.joints(ax, [], [], [])
    (tgt,) = ax.plot([], [], [], "x", color=st.TARGET, ms=9, mew=2.5, label="target")
    st.legend(ax, fontsize=6)
    ax.set_title(title, fontsize=9)

    def put(line, a):
        u, v, w = _xzy(a)
        line.set_data(u, v)
        line.set_3d_properties(w)

    frames = range(0, len(P), max(1, int(stride)))
    with GifWriter(fig, path, fps, dpi) as writer:
        for t in frames:
            put(bones, P[t])
            put(discs, P[t])
            put(trail, P[: t + 1, -1])
            put(tgt, targets[t])
            writer.grab()
    return len(frames)

