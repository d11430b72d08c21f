"""``curves.from_image`` on speckled images: the cost of many small skeleton pieces.

Random speckle (each pixel foreground with probability 1 - density) makes thousands of
tiny skeleton pieces, the worst case for chaining strokes.  Times thinning and stroke
tracing apart, median of 3 runs.  Target: a 512x512 speckle image in under 5 s.

Run: ``python benchmarks/from_image.py``; writes ``benchmarks/results/from_image.json``.
"""

from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import time_plain, write  # noqa: E402

from jaxsim import _skeleton, curves  # noqa: E402


def main() -> None:
    rows = []
    for side in (128, 256, 384, 512):
        for density in (0.5, 0.9):
            img = (np.random.default_rng(side).random((side, side)) > density).astype(float)
            sk = _skeleton.thin(img > 0.5)
            strokes = _skeleton.trace_strokes(sk)
            row = {"side": side, "density": density, "skeleton_pixels": int(sk.sum()), "strokes": len(strokes),
                   "thin_s": time_plain(_skeleton.thin, img > 0.5)["run_s"],
                   "trace_s": time_plain(_skeleton.trace_strokes, sk)["run_s"],
                   "from_image_s": time_plain(curves.from_image, img)["run_s"]}
            rows.append(row)
            print(f"{side}x{side} density {density}: {row['skeleton_pixels']} skeleton pixels, {row['strokes']} strokes, "
                  f"from_image {row['from_image_s']:.2f} s (thin {row['thin_s']:.2f}, trace {row['trace_s']:.2f})", flush=True)
    worst = max(r["from_image_s"] for r in rows if r["side"] == 512)
    write("from_image", {"rows": rows, "target_512_s": 5.0, "worst_512_s": worst, "met": worst < 5.0})


if __name__ == "__main__":
    main()
