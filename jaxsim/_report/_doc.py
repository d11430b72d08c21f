"""The report being written: markdown blocks, tables, figures, and progress lines."""

from __future__ import annotations

import os
import time


class Doc:
    """Collects the report's markdown and figure files, and prints progress."""

    def __init__(self, out: str, quick: bool):
        self.out, self.quick = out, quick
        self.lines: list[str] = []
        self.tables: dict[str, list[dict]] = {}
        self.figures: list[str] = []
        self.facts: dict[str, float] = {}
        self.t0 = time.perf_counter()
        os.makedirs(out, exist_ok=True)

    def progress(self, msg: str) -> None:
        print(f"[report {time.perf_counter() - self.t0:6.1f}s] {msg}", flush=True)

    def md(self, *text: str) -> None:
        self.lines += list(text) + [""]

    def table(self, key: str, rows: list[dict], columns: dict[str, str], fmt: dict | None = None) -> None:
        """A markdown table of ``rows`` (dicts); ``columns`` maps keys to headers."""
        fmt = fmt or {}
        self.tables[key] = rows
        head = "| " + " | ".join(columns.values()) + " |"
        out = [head, "|" + "---|" * len(columns)]
        for r in rows:
            cells = []
            for k in columns:
                v = r.get(k, "")
                f = fmt.get(k)
                cells.append(f(v) if callable(f) else (format(v, f) if f and not isinstance(v, str) else str(v)))
            out.append("| " + " | ".join(cells) + " |")
        self.md(*out)

    def figure(self, fig, name: str, caption: str) -> str:
        path = os.path.join(self.out, name)
        fig.savefig(path, dpi=fig.dpi)
        self.figures.append(name)
        self.md(f"![{caption}]({name})", "", f"*{caption}*")
        return path

    def write(self) -> str:
        path = os.path.join(self.out, "report.md")
        with open(path, "w") as f:
            f.write("\n".join(self.lines).rstrip() + "\n")
        return path


def sci(v) -> str:
    return "" if v == "" else f"{v:.2e}"


def fig_axes(ncols: int = 1, nrows: int = 1, w: float = 5.0, h: float = 3.6, dpi: int = 72):
    """A Figure with a grid of axes on an Agg canvas (small PNGs)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w * ncols, h * nrows), dpi=dpi)
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes
