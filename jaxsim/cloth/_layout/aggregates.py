"""The two-level preconditioner's aggregates: groups of particles, fixed per scene layout.

Square blocks of the particle grid on a grid scene (:func:`grid_block`, :func:`block_ids`),
else the cells of a voxel grid over the rest shape (:func:`aggregate`); ``_implicit.coarse`` builds
the coarse space on them.
"""

from __future__ import annotations

import numpy as np

#: Largest number of aggregates: the coarse matrix is at most ``3 * 64 = 192`` square.
MAX_AGGREGATES = 64


def aggregate(rest, max_aggregates: int = MAX_AGGREGATES) -> tuple[np.ndarray, int]:
    """Group particles into the cells of the coarsest voxel grid with few enough occupied cells.

    Args:
      rest: ``(N, 3)`` rest positions (m), concrete.
      max_aggregates: most aggregates allowed.

    Returns:
      ``(ids (N,) int32, count)``: each particle's aggregate in ``[0, count)``.
    """
    x = np.asarray(rest, np.float64).reshape(-1, 3)
    N = len(x)
    if N <= 1:
        return np.zeros(N, np.int32), 1
    lo, span = x.min(axis=0), np.ptp(x, axis=0)
    cell = max(float(span.max()), 1e-300) / (2 * max_aggregates)
    while True:
        # the same number of particles per cell along each axis: split each axis evenly
        n = np.maximum(np.ceil(span / cell), 1)
        width = np.where(span > 0, span / n, 1.0)
        cells = np.minimum(np.floor((x - lo) / width), n - 1).astype(np.int64)
        keys = (cells[:, 0] * int(n[1]) + cells[:, 1]) * int(n[2]) + cells[:, 2]  # one int per cell
        _, ids = np.unique(keys, return_inverse=True)
        count = int(ids.max()) + 1
        if count <= max_aggregates:
            return ids.reshape(-1).astype(np.int32), count
        cell *= 1.25


def grid_block(rows: int, cols: int, max_aggregates: int = MAX_AGGREGATES) -> int:
    """Side ``b`` of the square particle blocks that aggregate a ``rows x cols`` grid: the
    smallest with at most ``max_aggregates`` blocks."""
    b = 1
    while np.prod(block_grid(rows, cols, b)) > max_aggregates:
        b += 1
    return b


def block_grid(rows: int, cols: int, b: int) -> tuple[int, int]:
    """``(nI, nJ)``: the blocks of side ``b`` along each axis of a ``rows x cols`` grid."""
    return -(-rows // b), -(-cols // b)


def block_ids(rows: int, cols: int, b: int) -> np.ndarray:
    """``(rows * cols,)`` int32: particle ``(r, c)``'s block ``(r // b, c // b)``, row-major."""
    r, c = np.divmod(np.arange(rows * cols), cols)
    return ((r // b) * block_grid(rows, cols, b)[1] + c // b).astype(np.int32)
