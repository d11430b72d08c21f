"""Shared figure helpers: Agg canvases, saving, and text rendered into an array."""

from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure


def new_figure(width: float = 5.0, height: float = 4.0, dpi: int = 80, projection: str | None = None):
    """A ``(Figure, Axes)`` pair on its own Agg canvas (``projection="3d"`` for 3D axes)."""
    fig = Figure(figsize=(width, height), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1, projection=projection)
    return fig, ax


def save(fig, path: str, dpi: int | None = None) -> str:
    """Write ``fig`` to ``path`` and return the path of the file written.

    The format comes from the suffix; a path without one gets matplotlib's default
    format (``.png``) appended, and the returned path says so.
    """
    import os

    import matplotlib

    path = os.fspath(path)
    if not os.path.splitext(path)[1]:
        path = f"{path}.{matplotlib.rcParams['savefig.format']}"
    fig.savefig(path, dpi=dpi)
    return path


def check_fps(fps) -> float:
    """Frames per second of a GIF: a finite number > 0."""
    from .._validate import check_real

    return check_real("fps", fps, minimum=0.0, strict=True)


def check_frames(name: str, a, shape_tail: tuple, *, frames: int | None = None) -> np.ndarray:
    """``a`` as a float array of shape ``(T, *shape_tail)`` with ``T >= 1`` (and ``T == frames``)."""
    a = np.asarray(a, np.float64)
    if a.ndim != 1 + len(shape_tail) or any(s is not None and s != d for s, d in zip(shape_tail, a.shape[1:])):
        want = "(T, " + ", ".join("*" if s is None else str(s) for s in shape_tail) + ")"
        raise ValueError(f"{name} must have shape {want}, got {a.shape}")
    if a.shape[0] == 0:
        raise ValueError(f"{name} has no frames")
    if frames is not None and a.shape[0] != frames:
        raise ValueError(f"{name} has {a.shape[0]} frames but the result has {frames}")
    if not np.all(np.isfinite(a)):
        bad = np.flatnonzero(~np.all(np.isfinite(a.reshape(len(a), -1)), axis=1))
        raise ValueError(f"{name} has NaN or infinite values in {bad.size} frames (first: frame {bad[0]})")
    return a


def render_text(text: str, px: int = 64, weight: str = "bold") -> np.ndarray:
    """Render ``text`` with matplotlib's text engine into a grey image.

    Args:
      text: the string, e.g. a digit.
      px: output side in pixels.
      weight: font weight.

    Returns:
      ``(px, px)`` float array, ink 1 on background 0.
    """
    fig = Figure(figsize=(1, 1), dpi=px)
    canvas = FigureCanvasAgg(fig)
    fig.text(0.5, 0.5, text, ha="center", va="center", fontsize=0.8 * 72, weight=weight)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    return 1.0 - rgba[..., 0].astype(np.float64) / 255.0


def world_cube(ax, mid, half):
    """Cube limits ``mid +- half`` on 3D axes that draw world ``(x, z, y)`` (y up on the
    plot's vertical axis), with axis labels."""
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[2] - half, mid[2] + half)
    ax.set_zlim(mid[1] - half, mid[1] + half)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_zlabel("y (m)")
    from ._style import tidy_3d

    tidy_3d(ax)


def world_limits(ax, pts, floor: float | None = None):
    """:func:`world_cube` around ``pts (..., 3)`` with a 10% margin; returns the centre and
    half-width.  ``floor``: a height (m) that the box stands on (a horizontal plane
    collider), so the floor is the bottom of the box rather than a slab floating in it."""
    pts = np.asarray(pts).reshape(-1, 3)
    lo, hi = pts.min(0), pts.max(0)
    c, r = 0.5 * (lo + hi), 0.55 * max(np.max(hi - lo), 1e-3)
    if floor is not None:
        c = c.copy()
        c[1] = floor + 0.95 * r
    world_cube(ax, c, r)
    return c, r
