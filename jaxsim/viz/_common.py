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
    """Write ``fig`` to ``path`` (format from the suffix) and return the path."""
    fig.savefig(path, dpi=dpi)
    return path


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
