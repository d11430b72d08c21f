"""GIF frames from Agg figures: sized for a slide, quantised without dithering (Pillow)."""

from __future__ import annotations

import math
import os

import numpy as np

#: The short side of every GIF the package writes by default (pixels).
MIN_SIDE = 480


def gif_dpi(fig, dpi: float | None = None) -> float:
    """``dpi``, or (``None``) the least that makes ``fig``'s short side ``MIN_SIDE`` pixels."""
    if dpi is not None:
        from .._validate import check_real

        return check_real("dpi", dpi, minimum=0.0, strict=True)
    return math.ceil(MIN_SIDE / min(fig.get_size_inches()))


class GifWriter:
    """Collects frames of one figure and writes them as an animated GIF.

    Each frame is the figure's Agg canvas, quantised to an adaptive palette of at most
    255 colours *without* dithering (flat fills stay flat; matplotlib's own writer
    dithers), and the file loops forever.  Use as a context manager; :meth:`grab` adds
    the figure as it is drawn now.

    Args:
      fig: a ``matplotlib.figure.Figure`` on an Agg canvas.
      path: output path (``.gif``).
      fps: frames per second.
      dpi: the figure's resolution while writing (see :func:`gif_dpi`).
    """

    def __init__(self, fig, path: str, fps: float, dpi: float):
        self.fig, self.path, self.fps = fig, os.fspath(path), float(fps)
        self.frames = []
        fig.set_dpi(dpi)

    def __enter__(self):
        return self

    def grab(self) -> None:
        from PIL import Image

        canvas = self.fig.canvas
        canvas.draw()
        rgb = np.asarray(canvas.buffer_rgba())[..., :3]
        img = Image.fromarray(np.ascontiguousarray(rgb))
        self.frames.append(img.quantize(colors=255, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE))

    def __exit__(self, kind, value, tb):
        if kind is None and self.frames:
            duration = max(int(round(1000.0 / self.fps)), 20)  # ms; most viewers clamp below 20
            self.frames[0].save(self.path, save_all=True, append_images=self.frames[1:], duration=duration, loop=0,
                                disposal=1, optimize=False)
        self.frames = []
        return False
