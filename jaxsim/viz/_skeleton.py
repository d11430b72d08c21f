"""Drawing skeletons (joint trees): front and side views together, or one 3D view.

Front is the x-y plane (the humanoid faces +z), side the z-y plane.  Effectors are
ringed, targets are red crosses, and effector trails are thin lines.
"""

from __future__ import annotations

import numpy as np

from . import _style as st
from ._common import check_fps, check_frames, world_cube
from ._gif import GifWriter, gif_dpi

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


def _figure(views, dpi, size=3.2, everything=None):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if views == "3d":
        fig = Figure(figsize=(size + 0.8, size + 0.8), dpi=dpi)
        FigureCanvasAgg(fig)
        return fig, [fig.add_subplot(1, 1, 1, projection="3d")]
    ratios = None
    if everything is not None and views != "3d":  # each view as wide as its horizontal extent: one scale for all views
        lo, hi = np.nanmin(everything, axis=0), np.nanmax(everything, axis=0)
        ratios = [_half_extent(lo, hi, _VIEWS[v][0]) for v in views]
    width, height = size * len(views), size + 0.7  # the legend row below
    if ratios is not None:  # as tall as the drawing needs at that scale, plus titles, labels, legend
        v = _half_extent(lo, hi, 1)  # the same measure as the ratios
        height = float(np.clip((width - 0.8 * len(views)) * v / sum(ratios) + 1.6, 2.8, 1.4 * width))
        k = 4.2 / min(width, height)  # text sized for a short side of about 4 inches
        width, height = (width * k, height * k) if k < 1 else (width, height)
    fig = Figure(figsize=(width, height), dpi=dpi)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(views), squeeze=False, gridspec_kw={"width_ratios": ratios})[0]
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


def _half_extent(lo, hi, k):
    """Half the plotted range along world axis ``k``: the data's, plus 5 % of the largest
    extent (room for the effector rings), and at least 15 % of the largest."""
    big = float(np.max(hi - lo))
    return max(float(hi[k] - lo[k]) / 2 + 0.05 * big, 0.15 * big)


def _figure_legend(fig, ax):
    """One legend for all views, in a row under them (it covers no limb)."""
    handles, labels = ax.get_legend_handles_labels()
    top = 0.93 if fig.get_suptitle() else 1.0
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=len(handles), fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, 0.1 if handles else 0, 1, top))


def _frame(axes, views, everything):
    lo, hi = np.nanmin(everything, axis=0), np.nanmax(everything, axis=0)
    mid, half = (lo + hi) / 2, max(float(np.max(hi - lo)) / 2 * 1.1, 1e-3)
    for ax, view in zip(axes, ["3d"] if views == "3d" else views):
        if view == "3d":
            world_cube(ax, mid, half)
        else:  # each view as large as its own extent (the figure's width ratios follow them)
            i, j = _VIEWS[view]
            hu, hv = _half_extent(lo, hi, i), _half_extent(lo, hi, j)
            ax.set_xlim(mid[i] - hu, mid[i] + hu)
            ax.set_ylim(mid[j] - hv, mid[j] + hv)
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
    parts = [P]
    if targets is not None:
        parts.append(check_frames("targets", targets, (3,), frames=len(eff) or None))
    if trails is not None:
        trails = np.asarray(trails, np.float64)
        if trails.ndim != 3 or trails.shape[-1] != 3:
            raise ValueError(f"trails must have shape (T, E, 3), got {trails.shape}")
        parts.append(trails.reshape(-1, 3))
    fig, axes = _figure(views, dpi, everything=np.concatenate(parts))
    for k, (ax, view) in enumerate(zip(axes, ["3d"] if views == "3d" else views)):
        st.limbs(ax, *_segments(parents, P, view), label="bones")
        st.joints(ax, *_coords(P, view), label="joints")
        ax.plot(*_coords(P[:1], view), "s", color="k", ms=5, label="root")
        if eff:
            ax.plot(*_coords(P[eff], view), "o", mfc="none", mec=st.EFFECTOR, ms=11, mew=2, ls="none",
                    label="effectors")
        if targets is not None:
            ax.plot(*_coords(targets, view), "x", color=st.TARGET, ms=8, mew=2.5, ls="none", label="targets")
        if trails is not None:
            for e in range(trails.shape[1]):
                ax.plot(*_coords(trails[:, e], view), "-", color=st.EFFECTOR, lw=1.0,
                        label="effector paths" if e == 0 else None)
    _frame(axes, views, np.concatenate(parts))
    if title:
        fig.suptitle(title, fontsize=10)
    _figure_legend(fig, axes[0])
    return fig


def animate_skeleton(skeleton, positions, path: str, effectors=(), targets=None, views=("front", "side"),
                     fps: int = 30, stride: int = 1, title: str = "", dpi: float | None = None):
    """Write a GIF of a skeleton moving, with its effectors' trails and targets.

    Args:
      skeleton: a ``jaxsim.ik.Skeleton`` (or its ``parents`` tuple).
      positions: ``(T, J, 3)`` joint positions per frame (e.g. ``track(...).positions``).
      path: output ``.gif`` path.
      effectors: joint ids whose trails are drawn.
      targets: optional ``(T, E, 3)`` targets per frame.
      views, fps, stride: as in :func:`plot_skeleton`; every ``stride``-th frame is drawn.
      dpi: resolution; default the least that gives a short side of 480 px (``_gif``).

    Returns:
      The number of frames written.
    """
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
    parts = [P.reshape(-1, 3)] + ([targets.reshape(-1, 3)] if targets is not None else [])
    fig, axes = _figure(views, 80, everything=np.concatenate(parts))
    dpi = gif_dpi(fig, dpi)
    names = ["3d"] if views == "3d" else list(views)
    _frame(axes, views, np.concatenate(parts))
    if title:
        fig.suptitle(title, fontsize=10)
    arts = []
    empty = ([], [], []) if views == "3d" else ([], [])
    for k, ax in enumerate(axes):
        trails = [ax.plot(*empty, "-", color=st.EFFECTOR, lw=1.0, label="effector paths" if e == 0 else None)[0]
                  for e in range(len(eff))]
        bones, = st.limbs(ax, *empty, label="bones")
        discs, = st.joints(ax, *empty)
        rings, = ax.plot(*empty, "o", mfc="none", mec=st.EFFECTOR, ms=11, mew=2, ls="none", label="effectors")
        crosses, = ax.plot(*empty, "x", color=st.TARGET, ms=8, mew=2.5, ls="none",
                           label="targets" if targets is not None else None)
        arts.append((bones, discs, rings, crosses, trails))
    _figure_legend(fig, axes[0])

    def put(line, coords):
        line.set_data(coords[0], coords[1])
        if len(coords) == 3:
            line.set_3d_properties(coords[2])

    frames = range(0, len(P), max(1, int(stride)))
    with GifWriter(fig, path, fps, dpi) as writer:
        for t in frames:
            for view, (bones, discs, rings, crosses, trails) in zip(names, arts):
                put(bones, _segments(parents, P[t], view))
                put(discs, _coords(P[t], view))
                if eff:
                    put(rings, _coords(P[t, eff], view))
                if targets is not None:
                    put(crosses, _coords(targets[t], view))
                for k, line in enumerate(trails):
                    put(line, _coords(P[: t + 1, eff[k]], view))
            writer.grab()
    return len(frames)
