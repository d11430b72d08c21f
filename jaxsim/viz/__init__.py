"""Plotting and animation with matplotlib (imported only here, never by ``import jaxsim``).

Every function draws on an Agg canvas of its own (no pyplot, no display needed) unless
an ``ax`` is passed, returns the matplotlib ``Figure``, and writes a file when given a
path.  GIFs (``_gif``) are at least 480 px on their short side by default, quantised by
Pillow without dithering; every drawing shares one palette (``_style``) and has a legend.
"""

from ._cloth import animate_cloth, plot_cloth
from ._common import new_figure, render_text, save
from ._ik import animate_tracking, plot_chain, plot_tracking
from ._plots import plot_error_vs_time
from ._skeleton import animate_skeleton, plot_skeleton
from ._surface import animate_surface, plot_surface

__all__ = ["plot_chain", "plot_tracking", "animate_tracking", "plot_skeleton", "animate_skeleton", "plot_cloth", "animate_cloth", "plot_surface", "animate_surface",
           "plot_error_vs_time", "render_text", "new_figure", "save"]
