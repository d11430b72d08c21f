"""Drawing IK chains and tracked trajectories (side view on the x-z target plane is not
enough for a 3D chain, so the chain is shown in the x-y plane the lab draws it in, with
targets projected the same way: ``plane`` picks the two world axes)."""

from __future__ import annotations

import numpy as np

from ._common import check_fps, check_frames, new_figure

_AXES = {"xy": (0, 1), "xz": (0, 2), "zy": (2, 1)}


def _check_plane(plane):
    if plane not in _AXES:
        raise ValueError(f"plane must be one of {sorted(_AXES)}, got {plane!r}")


def _proj(a, plane):
    _check_plane(plane)
    i, j = _AXES[plane]
    a = np.asarray(a, np.float64)
    return a[..., i], a[..., j]


def plot_chain(positions, target=None, ax=None, plane: str = "xz", color: str = "C0"):
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
    ax.plot(u, v, "-o", color=color, lw=2, ms=4, label="chain")
    ax.plot(u[:1], v[:1], "ks", ms=6, label="root")
    if target is not None:
        tu, tv = _proj(target, plane)
        ax.plot([tu], [tv], "rx", ms=8, mew=2, label="target")
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
    ax.plot(tu, tv, ":", color="0.5", label="target path")
    eu, ev = _proj(P[:, -1], plane)
    ax.plot(eu, ev, "-", color="C1", lw=1, label="end-effector trail")
    plot_chain(P[-1], targets[-1], ax=ax, plane=plane)
    ax.legend(loc="best", fontsize=7)
    ax2.semilogy(np.arange(len(err)), np.maximum(err, 1e-16), color="C2", label="|end - target|")
    ax2.set_xlabel("frame")
    ax2.set_ylabel("error (m)")
    ax2.legend(fontsize=7)
    fig.tight_layout()
    return fig


def animate_tracking(result, targets, path: str, plane: str = "xz", fps: int = 30, stride: int = 1,
                     title: str = "", dpi: int = 60):
    """Write a GIF of the chain tracing ``targets`` with the target path and the trail.

    Args:
      result: ``IKResult`` from ``jaxsim.ik.track`` on a chain.
      targets: ``(T, 1, 3)`` or ``(T, 3)``.
      path: output ``.gif`` path.
      fps: frames per second of the GIF.
      stride: draw every ``stride``-th frame.

    Returns:
      The number of frames written.
    """
    from matplotlib.animation import PillowWriter

    _check_plane(plane)
    fps = check_fps(fps)
    P = check_frames("result.positions", result.positions, (None, 3))
    targets = check_frames("targets", _end_targets(targets), (3,), frames=len(P))
    fig, ax = new_figure(4, 4, dpi=dpi)
    _frame_axes(ax, targets, P, plane, title)
    tu, tv = _proj(targets, plane)
    ax.plot(tu, tv, ":", color="0.5", label="target path")
    (trail,) = ax.plot([], [], "-", color="C1", lw=1, label="end-effector trail")
    (bones,) = ax.plot([], [], "-o", color="C0", lw=2, ms=4, label="chain")
    (tgt,) = ax.plot([], [], "rx", ms=8, mew=2, label="target")
    ax.legend(loc="upper right", fontsize=6)
    fig.tight_layout()
    frames = range(0, len(P), max(1, int(stride)))
    writer = PillowWriter(fps=fps)
    with writer.saving(fig, path, dpi):
        for t in frames:
            bones.set_data(*_proj(P[t], plane))
            trail.set_data(*_proj(P[: t + 1, -1], plane))
            tgt.set_data(*[[c] for c in _proj(targets[t], plane)])
            writer.grab_frame()
    return len(frames)
