"""Image to IK trajectory: threshold, thin to a skeleton, trace strokes, fit into reach.

Pure numpy.  The thinning is Zhang & Suen's two-subiteration algorithm ("A fast parallel
algorithm for thinning digital patterns", CACM 27(3), 1984); strokes are traced over the
8-connected skeleton graph by a depth-first walk that retraces its way back out of
dead-end branches, so the pen only lifts between separate pieces of the skeleton.
"""

from __future__ import annotations

import numpy as np

from ._resample import resample_arclength

# 8-neighbours in Zhang-Suen order P2..P9 (clockwise from north): (drow, dcol)
_NB = [(-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1)]


def _neighbours(img: np.ndarray) -> list[np.ndarray]:
    p = np.pad(img, 1)
    H, W = img.shape
    return [p[1 + dr:1 + dr + H, 1 + dc:1 + dc + W] for dr, dc in _NB]


def thin(mask) -> np.ndarray:
    """Zhang-Suen thinning of a boolean image to a one-pixel-wide 8-connected skeleton.

    Args:
      mask: ``(H, W)`` boolean foreground.

    Returns:
      ``(H, W)`` boolean skeleton (a subset of ``mask``).
    """
    img = np.asarray(mask, bool).copy()
    while True:
        changed = False
        for step in (0, 1):
            P = [n.astype(np.int8) for n in _neighbours(img)]
            B = sum(P)
            seq = P + [P[0]]
            A = sum(((seq[k] == 0) & (seq[k + 1] == 1)).astype(np.int8) for k in range(8))
            p2, p4, p6, p8 = P[0], P[2], P[4], P[6]
            if step == 0:
                c = (p2 * p4 * p6 == 0) & (p4 * p6 * p8 == 0)
            else:
                c = (p2 * p4 * p8 == 0) & (p2 * p6 * p8 == 0)
            kill = img & (B >= 2) & (B <= 6) & (A == 1) & c
            if kill.any():
                img &= ~kill
                changed = True
        if not changed:
            return img


def _nearest_start(todo: np.ndarray, deg: np.ndarray, pos: tuple[int, int]) -> tuple[int, int]:
    """The unvisited pixel nearest to ``pos`` (ties: an end pixel first, then the first in
    row-major order), found in square windows of doubling radius around ``pos``.

    Its cost grows with the distance searched, not with the image, so tracing an image
    with many small pieces stays linear in its pixels.
    """
    H, W = todo.shape
    r0, c0 = pos

    def window(r):
        top, left = max(r0 - r, 0), max(c0 - r, 0)
        found = np.argwhere(todo[top:r0 + r + 1, left:c0 + r + 1])
        return found + (top, left)

    r = 1
    while True:
        cand = window(r)
        if len(cand):
            break
        if r > max(H, W):
            raise AssertionError("no unvisited pixel left")  # callers check there is one
        r *= 2
    d2 = np.sum((cand - (r0, c0)) ** 2, axis=1)
    reach = int(np.ceil(np.sqrt(d2.min())))  # every pixel as near lies in this window
    if reach > r:
        cand = window(reach)
        d2 = np.sum((cand - (r0, c0)) ** 2, axis=1)
    near = cand[d2 == d2.min()]
    ends = near[deg[near[:, 0], near[:, 1]] == 1]
    pick = ends if len(ends) else near
    pick = pick[np.lexsort((pick[:, 1], pick[:, 0]))]
    return int(pick[0, 0]), int(pick[0, 1])


def trace_strokes(skeleton) -> list[np.ndarray]:
    """Order skeleton pixels into strokes drawn with as few pen lifts as the image allows.

    Each 8-connected piece of the skeleton becomes one stroke: a depth-first walk from
    an end pixel (or any pixel of a loop) that steps only to 8-neighbours, retracing its
    path back out of dead ends, so every pixel is visited and consecutive points are at
    most ``sqrt(2)`` pixels apart.  The walk stops at the last new pixel.  Pieces are
    chained greedily: the next stroke starts at the unvisited pixel nearest to where the
    last one ended, so the only pen jumps are the gaps between pieces.  The nearest
    pixel is searched in growing windows (``_nearest_start``), so the whole trace is
    linear in the number of pixels for any number of pieces.

    Args:
      skeleton: ``(H, W)`` boolean image.

    Returns:
      list of ``(K, 2)`` integer ``(row, col)`` arrays, one per stroke, in drawing order.
    """
    sk = np.asarray(skeleton, bool)
    H, W = sk.shape
    deg = sum(n.astype(np.int8) for n in _neighbours(sk)) * sk
    todo = sk.copy()  # pixels not visited yet
    remaining = int(sk.sum())
    strokes = []
    pos = None
    order = _NB[0::2] + _NB[1::2]  # 4-neighbours first: fewer diagonal zig-zags
    while remaining:
        if pos is None:
            rest = np.argwhere(todo)  # row-major order
            ends = rest[deg[rest[:, 0], rest[:, 1]] == 1]
            start = tuple(int(v) for v in (ends if len(ends) else rest)[0])
        else:
            start = _nearest_start(todo, deg, pos)
        path, stack = [start], [start]
        todo[start] = False
        remaining -= 1
        last_new = 0
        while stack:
            r, c = stack[-1]
            nxt = None
            for dr, dc in order:
                q = (r + dr, c + dc)
                if 0 <= q[0] < H and 0 <= q[1] < W and todo[q]:
                    nxt = q
                    break
            if nxt is None:
                stack.pop()
                if stack:
                    path.append(stack[-1])  # retrace
                continue
            todo[nxt] = False
            remaining -= 1
            stack.append(nxt)
            path.append(nxt)
            last_new = len(path)
        path = path[:last_new] if last_new else path[:1]
        strokes.append(np.asarray(path, np.int64))
        pos = path[-1]
    return strokes


def from_image(image, threshold: float = 0.5, size: float = 0.6, invert: bool = False,
               n: int | None = None) -> np.ndarray:
    """Turn a 2D binary or grey image into an IK trajectory.

    Steps: threshold (foreground is ``image > threshold``, or ``<`` with ``invert``),
    Zhang-Suen thinning, stroke tracing (:func:`trace_strokes`), and a uniform scale
    that fits the drawing into ``[-size, size]`` about the origin of the plane y = 0
    (image columns go to +x, rows to -z, so the picture is upright).  Pen jumps
    between strokes are kept as straight moves; ``n`` respaces the whole path with
    equal chords (:func:`jaxsim.curves.resample_arclength`).

    Args:
      image: ``(H, W)`` array; grey values are compared with ``threshold``.
      threshold: foreground threshold.
      size: half-extent of the fitted drawing (scene units).
      invert: foreground is dark (``image < threshold``).
      n: number of output points (``None``: one per traced pixel).

    Returns:
      ``(T, 3)`` targets.

    Raises:
      ValueError: if the image is not 2D or has no foreground.
    """
    img = np.asarray(image, np.float64)
    if img.ndim != 2:
        raise ValueError(f"image must be 2D (H, W), got shape {img.shape}")
    mask = img < threshold if invert else img > threshold
    if not mask.any():
        raise ValueError("image has no foreground pixels at this threshold")
    path = np.concatenate(trace_strokes(thin(mask)), axis=0).astype(np.float64)
    uv = np.stack([path[:, 1], -path[:, 0]], axis=-1)
    uv -= 0.5 * (uv.max(0) + uv.min(0))
    ext = np.max(np.abs(uv))
    uv *= size / (ext if ext > 0 else 1.0)
    if n is not None and len(uv) >= 2:
        uv = resample_arclength(uv, n)
    return np.stack([uv[:, 0], np.zeros(len(uv)), uv[:, 1]], axis=-1)
