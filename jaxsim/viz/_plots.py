"""Generic diagnostic plots."""

from __future__ import annotations

import numpy as np

from ._common import new_figure


def plot_error_vs_time(series, ax=None, xlabel: str = "wall time per solve (s)", ylabel: str = "error",
                       title: str = "", logx: bool = True, logy: bool = True, annotate: bool = False):
    """Error against run time: one marked line per method (a Pareto-style plot).

    Args:
      series: ``{label: (times, errors)}`` or ``{label: (times, errors, point_labels)}``.
      ax: axes to draw on (a new figure when ``None``).

    Returns:
      The figure.
    """
    if ax is None:
        fig, ax = new_figure(6, 4.5)
    for k, (label, s) in enumerate(series.items()):
        t, e = np.asarray(s[0], np.float64), np.asarray(s[1], np.float64)
        ax.plot(t, np.maximum(e, 1e-17), "-o", ms=4, color=f"C{k % 10}", label=label)
        if annotate and len(s) > 2:
            for ti, ei, name in zip(t, e, s[2]):
                ax.annotate(str(name), (ti, max(ei, 1e-17)), fontsize=6, xytext=(3, 3), textcoords="offset points")
    if logx:
        ax.set_xscale("log")
    if logy:
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=7)
    return ax.figure
