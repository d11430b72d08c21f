"""The regular grid's topology: its springs (structural, shear, bending) and its triangles."""

from __future__ import annotations

import numpy as np

from ..._validate import check_int
from .._layout.stencil import Stencil

#: The grid's spring families: offset of a spring's first particle from its second, and kind.
GRID_FAMILIES = (((-1, 0), 0), ((0, -1), 0), ((-1, -1), 1), ((-1, 1), 1), ((-2, 0), 2), ((0, -2), 2))


def grid_springs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Springs of an ``(n+1) x (n+1)`` particle grid, id ``i*(n+1) + j``.

    Returns ``(springs (S, 2), kind (S,))`` with kind 0 structural ``(i-1, j)``,
    ``(i, j-1)``; 1 shear ``(i-1, j-1)``, ``(i-1, j+1)``; 2 bending ``(i-2, j)``, ``(i, j-2)``
    (each spring joins particle ``(i, j)`` to the one at that offset).  The springs come
    family by family, each in row-major order of ``(i, j)``: the layout of the grid
    operator (``_layout.stencil``), which the scene then applies by shifted slices.
    """
    m = n + 1
    fams = [(o, k) for o, k in GRID_FAMILIES if abs(o[0]) < m and abs(o[1]) < m]
    st = Stencil(m, m, tuple(o for o, _ in fams))
    kinds = [np.full(st.count(f), k, np.int8) for f, (_, k) in enumerate(fams)]
    return st.springs().astype(np.int32), np.concatenate(kinds)


def grid_triangles(n: int) -> np.ndarray:
    """``(2 n^2, 3)`` triangles of ``grid(n)``'s particles, each cell split along its
    ``(i, j)``–``(i+1, j+1)`` diagonal (counter-clockwise seen from +y)."""
    n = check_int("grid_triangles n (cells per side)", n, 1)
    m = n + 1
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a, b, c, d = i * m + j, (i + 1) * m + j, (i + 1) * m + j + 1, i * m + j + 1
    t1 = np.stack([a, d, c], -1).reshape(-1, 3)
    t2 = np.stack([a, c, b], -1).reshape(-1, 3)
    return np.concatenate([t1, t2]).astype(np.int32)
