"""The grid operator: springs of a regular particle grid as shifted slices.

On a ``rows x cols`` grid (particle ``(r, c)`` has id ``r * cols + c``) whose springs come
in families, each family joining every particle to the one at a fixed offset
``(dr, dc)``, a per-spring difference ``v_j - v_i`` is a difference of two shifted
slices of the grid, and a per-particle sum of spring values is a sum of padded slices.
Neither needs an index array: no gather in the forward pass and, through autodiff, no
scatter in the reverse one.  The scene keeps its general operator (gathers through
``Cloth.incidence``) for any other layout.

:func:`detect` finds the layout from the spring list alone, at scene construction;
``grid`` and ``lab_cloth`` emit their springs family by family so that it does.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np


@dataclasses.dataclass(frozen=True)
class Stencil:
    """A grid layout of the springs (static, hashable).

    Attributes:
      rows, cols: particle grid shape; particle ``(r, c)`` has id ``r * cols + c``.
      offsets: per family, in spring order, the offset ``(dr, dc)`` of a spring's first
        particle ``i`` from its second ``j``.  Family ``f`` holds one spring for each
        ``j`` whose ``j + (dr, dc)`` lies on the grid, ``j`` in row-major order.
    """

    rows: int
    cols: int
    offsets: tuple[tuple[int, int], ...]

    def window(self, f: int) -> tuple[int, int, int, int]:
        """``(r0, r1, c0, c1)``: the second ends of family ``f`` are ``[r0:r1, c0:c1]``."""
        dr, dc = self.offsets[f]
        return max(0, -dr), min(self.rows, self.rows - dr), max(0, -dc), min(self.cols, self.cols - dc)

    def count(self, f: int) -> int:
        """Number of springs in family ``f``."""
        r0, r1, c0, c1 = self.window(f)
        return max(r1 - r0, 0) * max(c1 - c0, 0)

    def springs(self) -> np.ndarray:
        """``(S, 2)`` the spring list this layout stands for."""
        out = []
        for f, (dr, dc) in enumerate(self.offsets):
            r0, r1, c0, c1 = self.window(f)
            r, c = np.meshgrid(np.arange(r0, r1), np.arange(c0, c1), indexing="ij")
            j = (r * self.cols + c).reshape(-1)
            out.append(np.stack([j + dr * self.cols + dc, j], 1))
        return np.concatenate(out).astype(np.int64) if out else np.zeros((0, 2), np.int64)


#: Most spring families a grid layout may have (each is a few shifted slices per use).
MAX_FAMILIES = 16


def detect(springs, n_particles: int) -> Stencil | None:
    """The grid layout of ``springs (S, 2)`` over ``n_particles``, or ``None``.

    Tries every column count that divides ``n_particles``; the springs must be exactly
    the families of :class:`Stencil` (same ids, same order, no empty family).
    """
    springs = np.asarray(springs, np.int64).reshape(-1, 2)
    S = len(springs)
    if S == 0:
        return None
    i, j = springs[:, 0], springs[:, 1]
    for cols in range(2, n_particles + 1):
        if n_particles % cols:
            continue
        dr, dc = i // cols - j // cols, i % cols - j % cols
        starts = np.concatenate([[0], np.flatnonzero((np.diff(dr) != 0) | (np.diff(dc) != 0)) + 1])
        if len(starts) > MAX_FAMILIES:
            continue
        st = Stencil(n_particles // cols, cols, tuple((int(dr[s]), int(dc[s])) for s in starts))
        expect = st.springs()
        if expect.shape == springs.shape and np.array_equal(expect, springs):
            return st
    return None


def differences(st: Stencil, v):
    """``v_j - v_i`` for every spring: ``(N, ...) -> (S, ...)``."""
    tail = v.shape[1:]
    G = v.reshape((st.rows, st.cols) + tail)
    parts = []
    for f, (dr, dc) in enumerate(st.offsets):
        r0, r1, c0, c1 = st.window(f)
        parts.append((G[r0:r1, c0:c1] - G[r0 + dr:r1 + dr, c0 + dc:c1 + dc]).reshape((-1,) + tail))
    return jnp.concatenate(parts)


def sums(st: Stencil, f, signed: bool = True):
    """Per-particle sums of per-spring values ``f (S, ...) -> (N, ...)``: ``+f`` at each
    spring's second end, ``-f`` (``signed``) or ``+f`` at its first."""
    tail = f.shape[1:]
    out = jnp.zeros((st.rows, st.cols) + tail, f.dtype)
    pad_tail = [(0, 0)] * len(tail)
    k = 0
    for fam, (dr, dc) in enumerate(st.offsets):
        r0, r1, c0, c1 = st.window(fam)
        n = (r1 - r0) * (c1 - c0)
        F = f[k:k + n].reshape((r1 - r0, c1 - c0) + tail)
        k += n
        at_j = jnp.pad(F, [(r0, st.rows - r1), (c0, st.cols - c1)] + pad_tail)
        at_i = jnp.pad(F, [(r0 + dr, st.rows - r1 - dr), (c0 + dc, st.cols - c1 - dc)] + pad_tail)
        out = out + at_j + (-at_i if signed else at_i)
    return out.reshape((st.rows * st.cols,) + tail)
