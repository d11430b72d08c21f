"""The planar layout of a grid scene's CG loop: one plane per vector component.

A particle array ``(N, 3)`` has a minor axis of 3, and so do the spring blocks
``(S, 3, 3)``; XLA:CPU vectorises an elementwise loop along the minor axis, and a minor
axis of 3 leaves its vector units mostly empty.  On a grid scene (``_stencil``) the CG
loop of a Newton iteration runs instead on planes: vectors ``(3, rows, cols)``, spring
blocks ``(3, 3, S)``, per-particle blocks ``(3, 3, rows, cols)``.  Every elementwise loop
then runs along a grid row.  The spring operator ``v -> sum_s A_s (v_j - v_i)`` takes
about half the time of the ``(N, 3)`` one (B 32x32 and 128x128, float64; README "PCG on
planes").  Newton (``_hessian.HessianOps``) converts its right-hand side and warm start
once per solve, and forms the blocks in planes once per iteration.
"""

from __future__ import annotations

import jax.numpy as jnp

from ._stencil import Stencil


def to_planes(st: Stencil, v):
    """``(N, 3) -> (3, rows, cols)``."""
    return v.T.reshape((3, st.rows, st.cols))


def from_planes(V):
    """``(3, rows, cols) -> (N, 3)``."""
    return V.reshape((3, -1)).T


def particle_planes(st: Stencil, a):
    """Per-particle values ``(N,)`` as a plane ``(rows, cols)``; blocks ``(N, 3, 3)`` as ``(3, 3, rows, cols)``."""
    if a.ndim == 1:
        return a.reshape((st.rows, st.cols))
    return a.transpose(1, 2, 0).reshape((3, 3, st.rows, st.cols))


def radial_blocks(e, along, across, e0=None, d_over_h=None, *, project_psd: bool):
    """``(3, 3, S)`` blocks ``along e e^T + across (I - e e^T)`` (+ ``(d/h) e0 e0^T``) from
    ``e, e0 (S, 3)`` and ``along, across (S,)``: ``_energy.radial_blocks`` in planes."""
    if project_psd:
        along, across = jnp.maximum(along, 0.0), jnp.maximum(across, 0.0)
    e, e0 = e.T, None if e0 is None else e0.T
    diff = along - across
    rows = []
    for a in range(3):
        row = []
        for b in range(3):
            blk = diff * e[a] * e[b] + (across if a == b else 0.0)
            row.append(blk if e0 is None else blk + d_over_h * e0[a] * e0[b])
        rows.append(jnp.stack(row))
    return jnp.stack(rows)


def matvec(D, V):
    """``(3, 3, ...) x (3, ...) -> (3, ...)``, component by component."""
    return jnp.stack([D[a, 0] * V[0] + D[a, 1] * V[1] + D[a, 2] * V[2] for a in range(3)])


def _families(st: Stencil):
    """Per family: ``(offset into S, count, (r0, r1, c0, c1), (dr, dc))``."""
    k = 0
    for f, off in enumerate(st.offsets):
        r0, r1, c0, c1 = st.window(f)
        n = (r1 - r0) * (c1 - c0)
        yield k, n, (r0, r1, c0, c1), off
        k += n


def _at_both_ends(st: Stencil, F, win, off, signed: bool):
    """A family's per-spring values ``(..., r1-r0, c1-c0)`` padded to the grid at the
    second ends (``+F``) and the first ends (``-F`` when ``signed``)."""
    (r0, r1, c0, c1), (dr, dc) = win, off
    lead = [(0, 0)] * (F.ndim - 2)
    at_j = jnp.pad(F, lead + [(r0, st.rows - r1), (c0, st.cols - c1)])
    at_i = jnp.pad(F, lead + [(r0 + dr, st.rows - r1 - dr), (c0 + dc, st.cols - c1 - dc)])
    return at_j - at_i if signed else at_j + at_i


def operator(st: Stencil, A, V):
    """``sum_s A_s (v_j - v_i)`` at each spring's second end, minus it at the first:
    ``A (3, 3, S)``, ``V (3, rows, cols) -> (3, rows, cols)``, family by family."""
    out = jnp.zeros_like(V)
    for k, n, (r0, r1, c0, c1), (dr, dc) in _families(st):
        D = V[:, r0:r1, c0:c1] - V[:, r0 + dr:r1 + dr, c0 + dc:c1 + dc]
        Af = A[:, :, k:k + n].reshape((3, 3, r1 - r0, c1 - c0))
        out = out + _at_both_ends(st, matvec(Af, D), (r0, r1, c0, c1), (dr, dc), signed=True)
    return out


def block_sums(st: Stencil, A):
    """``(3, 3, S) -> (3, 3, rows, cols)``: each particle's sum of its springs' blocks."""
    out = jnp.zeros((3, 3, st.rows, st.cols), A.dtype)
    for k, n, (r0, r1, c0, c1), off in _families(st):
        Af = A[:, :, k:k + n].reshape((3, 3, r1 - r0, c1 - c0))
        out = out + _at_both_ends(st, Af, (r0, r1, c0, c1), off, signed=False)
    return out
