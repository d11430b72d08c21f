"""Drawing the cloth as a 3D wireframe of its springs."""

from __future__ import annotations

import numpy as np

from . import _style as st
from ._common import check_fps, check_frames, new_figure, world_limits
from ._gif import GifWriter, gif_dpi


def _segments(springs, x):
    return np.stack([x[springs[:, 0]], x[springs[:, 1]]], axis=1)  # (S, 2, 3)


def _setup(ax, cloth, xs):
    world_limits(ax, xs)


def _structural(cloth):
    """Springs drawn: structural ones only when the scene has them tagged by length."""
    springs = np.asarray(cloth.springs)
    rest = np.asarray(cloth.rest_length)
    short = rest <= rest.min() * (1 + 1e-6)
    return springs[short] if short.sum() > 0 else springs


def plot_cloth(cloth, x, ax=None, title: str = ""):
    """Draw the cloth at positions ``x (N, 3)``: shortest springs as a wireframe, pinned
    particles as red dots.  Returns the figure."""
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    x = np.asarray(x, np.float64)
    if x.shape != (cloth.num_particles, 3):
        raise ValueError(f"x must have shape ({cloth.num_particles}, 3), got {x.shape}")
    if ax is None:
        fig, ax = new_figure(4.5, 4.5, projection="3d")
    _setup(ax, cloth, x)
    seg = _segments(_structural(cloth), x)[..., [0, 2, 1]]
    ax.add_collection3d(Line3DCollection(seg, colors=st.WIRE, linewidths=0.8, label="springs"))
    pin = np.asarray(cloth.pinned)
    ax.scatter(x[pin, 0], x[pin, 2], x[pin, 1], color=st.PIN, s=16, label="pinned")
    st.legend(ax)
    ax.set_title(title)
    return ax.figure


def animate_cloth(cloth, xs, path: str, fps: int = 30, stride: int = 1, title: str = "", dpi: float | None = None):
    """Write a GIF of the cloth over the positions ``xs (T, N, 3)``: the structural springs
    as a wireframe, pins as red dots.  ``dpi``: default the least that gives a short side
    of 480 px (``_gif``).  Returns the frame count."""
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    fps = check_fps(fps)
    xs = check_frames("xs", xs, (cloth.num_particles, 3))
    fig, ax = new_figure(4, 4, projection="3d")
    dpi = gif_dpi(fig, dpi)
    _setup(ax, cloth, xs)
    springs = _structural(cloth)
    lines = Line3DCollection(_segments(springs, xs[0])[..., [0, 2, 1]], colors=st.WIRE, linewidths=0.8,
                             label="springs")
    ax.add_collection3d(lines)
    pin = np.asarray(cloth.pinned)
    ax.scatter(xs[0, pin, 0], xs[0, pin, 2], xs[0, pin, 1], color=st.PIN, s=16, label="pinned")
    st.legend(ax)
    txt = ax.set_title(title, fontsize=9)
    frames = range(0, len(xs), max(1, int(stride)))
    with GifWriter(fig, path, fps, dpi) as writer:
        for t in frames:
            lines.set_segments(_segments(springs, xs[t])[..., [0, 2, 1]])
            txt.set_text(f"{title}  t = {t + 1} steps" if title else f"step {t + 1}")
            writer.grab()
    return len(frames)
