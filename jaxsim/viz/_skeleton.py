"""Drawing skeletons (joint trees): front and side views together, or one 3D view.

Front is the x-y plane (the humanoid faces +z), side the z-y plane.  Effectors are
ringed, targets are red crosses, and effector trails are thin lines.
"""

from __future__ import annotations

import numpy as np

from ._common import check_fps, check_frames, world_cube

_VIEWS = {"front": (0, 1), "side": (2, 1)}


def _parents(skeleton):
    parents = getattr(skeleton, "parents", skeleton)
    return tuple(int(p) for p in parents)


def _check_views(views):
    if views == "3d":
        return views
    views = tuple(views)
    if not views or any(v not in _VIEWS for v in views):
        raise ValueError(f"views must be '3d' or a sequence of {sorted(_VIEWS)}, got {views!r}")
    return views


def _figure(views, dpi, size=3.2):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if views == "3d":
        fig = Figure(figsize=(size + 0.8, size + 0.8), dpi=dpi)
        FigureCanvasAgg(fig)
        return fig, [fig.add_subplot(1, 1, 1, projection="3d")]
    fig = Figure(figsize=(size * len(views), size + 0.4), dpi=dpi)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(views), squeeze=False)[0]
    return fig, list(axes)


def _segments(parents, P, view):
    """Bone polyline with NaN breaks, in the view's coordinates."""
    pts = []
    for i, p in enumerate(parents[1:], start=1):
        pts += [P[p], P[i], np.full(3, np.nan)]
    pts = np.array(pts)
    if view == "3d":
        return pts[:, 0], pts[:, 2], pts[:, 1]
    i, j = _VIEWS[view]
    return pts[:, i], pts[:, j]


def _coords(a, view):
    a = np.asarray(a, np.float64).reshape(-1, 3)
    if view == "3d":
        return a[:, 0], a[:, 2], a[:, 1]
    i, j = _VIEWS[view]
    return a[:, i], a[:, j]


def _frame(axes, views, everything):
    lo, hi = np.nanmin(everything, axis=0), np.nanmax(everything, axis=0)
    mid, half = (lo + hi) / 2, max(float(np.max(hi - lo)) / 2 * 1.1, 1e-3)
    for ax, view in zip(axes, ["3d"] if views == "3d" else views):
        if view == "3d":
            world_cube(ax, mid, half)
        else:
            i, j = _VIEWS[view]
            ax.set_xlim(mid[i] - half, mid[i] + half)
            ax.set_ylim(mid[j] - half, mid[j] + half)
            ax.set_aspect("equal")
            ax.set_xlabel(f"{'xyz'[i]} (m)")
            ax.set_ylabel("y (m)")
            ax.set_title(view, fontsize=9)


def plot_skeleton(skeleton, positions, effectors=(), targets=None, trails=None, views=("front", "side"),
                  title: str = "", dpi: int = 80):
    """Draw one pose of a skeleton.

    Args:
      skeleton: a ``jaxsim.ik.Skeleton`` (or its ``parents`` tuple).
      positions: ``(J, 3)`` joint world positions (metres).
      effectors: joint ids to ring.
      targets: optional ``(E, 3)`` targets, drawn as red crosses.
      trails: optional ``(T, E, 3)`` effector paths, drawn as thin lines.
      views: ``("front", "side")`` (any non-empty subset, in order) or ``"3d"``.

    Returns:
      The figure.
    """
    parents = _parents(skeleton)
    views = _check_views(views)
    P = check_frames("positions", positions, (3,), frames=len(parents))
    eff = [int(e) for e in effectors]
    fig, axes = _figure(views, dpi)
    parts = [P]
    if targets is not None:
        parts.append(check_frames("targets", targets, (3,), frames=len(eff) or None))
    if trails is not None:
        trails = np.asarray(trails, np.float64)
        if trails.ndim != 3 or trails.shape[-1] != 3:
            raise ValueError(f"trails must have shape (T, E, 3), got {trails.shape}")
        parts.append(trails.reshape(-1, 3))
    for ax, view in zip(axes, ["3d"] if views == "3d" else views):
        ax.plot(*_segments(parents, P, view), "-", color="C0", lw=2)
        ax.plot(*_coords(P, view), "o", color="C0", ms=3)
        ax.plot(*_coords(P[:1], view), "ks", ms=5)
        if eff:
            ax.plot(*_coords(P[eff], view), "o", mfc="none", mec="C1", ms=9, mew=1.5)
        if targets is not None:
            ax.plot(*_coords(targets, view), "rx", ms=7, mew=2)
        if trails is not None:
            for k in range(trails.shape[1]):
                ax.plot(*_coords(trails[:, k], view), "-", color="C1", lw=0.8)
    _frame(axes, views, np.concatenate(parts))
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def animate_skeleton(skeleton, positions, path: str, effectors=(), targets=None, views=("front", "side"),
                     fps: int = 30, stride: int = 1, title: str = "", dpi: int = 60):
    """Write a GIF of a skeleton moving, with its effectors' trails and targets.

    Args:
      skeleton: a ``jaxsim.ik.Skeleton`` (or its ``parents`` tuple).
      positions: ``(T, J, 3)`` joint positions per frame (e.g. ``track(...).positions``).
      path: output ``.gif`` path.
      effectors: joint ids whose trails are drawn.
      targets: optional ``(T, E, 3)`` targets per frame.
      views, fps, stride: as in :func:`plot_skeleton`; every ``stride``-th frame is drawn.

    Returns:
      The number of frames written.
    """
    from matplotlib.animation import PillowWriter

    parents = _parents(skeleton)
    views = _check_views(views)
    fps = check_fps(fps)
    P = np.asarray(positions, np.float64)
    if P.ndim != 3 or P.shape[1:] != (len(parents), 3) or not np.all(np.isfinite(P)):
        raise ValueError(f"positions must be finite with shape (T, {len(parents)}, 3), got {P.shape}")
    eff = [int(e) for e in effectors]
    if targets is not None:
        targets = np.asarray(targets, np.float64)
        if targets.shape != (len(P), len(eff), 3):
            raise ValueError(f"targets must have shape ({len(P)}, {len(eff)}, 3), got {targets.shape}")
    fig, axes = _figure(views, dpi)
    names = ["3d"] if views == "3d" else list(views)
    parts = [P.reshape(-1, 3)] + ([targets.reshape(-1, 3)] if targets is not None else [])
    _frame(axes, views, np.concatenate(parts))
    if title:
        fig.suptitle(title, fontsize=10)
    arts = []
    for ax in axes:
        bones, = ax.plot([], [], "-", color="C0", lw=2)
        rings, = ax.plot([], [], "o", mfc="none", mec="C1", ms=8, mew=1.5)
        crosses, = ax.plot([], [], "rx", ms=7, mew=2)
        trails = [ax.plot([], [], "-", color="C1", lw=0.8)[0] for _ in eff]
        arts.append((bones, rings, crosses, trails))
    fig.tight_layout()

    def put(line, coords):
        line.set_data(coords[0], coords[1])
        if len(coords) == 3:
            line.set_3d_properties(coords[2])

    frames = range(0, len(P), max(1, int(stride)))
    writer = PillowWriter(fps=fps)
    with writer.saving(fig, path, dpi):
        for t in frames:
            for view, (bones, rings, crosses, trails) in zip(names, arts):
                put(bones, _segments(parents, P[t], view))
                if eff:
                    put(rings, _coords(P[t, eff], view))
                if targets is not None:
                    put(crosses, _coords(targets[t], view))
                for k, line in enumerate(trails):
                    put(line, _coords(P[: t + 1, eff[k]], view))
            writer.grab_frame()
    return len(frames)
