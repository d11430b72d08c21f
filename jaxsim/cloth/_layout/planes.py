"""The planar layout of a grid scene's CG loop: one plane per vector component.

A particle array ``(N, 3)`` has a minor axis of 3, and so do the spring blocks
``(S, 3, 3)``; XLA:CPU vectorises an elementwise loop along the minor axis, and a minor
axis of 3 leaves its vector units mostly empty.  On a grid scene (``_layout.stencil``) the CG
loop of a Newton iteration runs instead on planes: vectors ``(3, rows, cols)``, spring
blocks ``(3, 3, S)``, per-particle blocks ``(3, 3, rows, cols)``.  Every elementwise loop
then runs along a grid row.  The spring operator ``v -> sum_s A_s (v_j - v_i)`` takes
about half the time of the ``(N, 3)`` one (B 32x32 and 128x128, float64; README "PCG on
planes").  Newton (``_implicit.hessian.HessianOps``) converts its right-hand side and warm start
once per solve, and forms the blocks in planes once per iteration.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .aggregates import block_grid
from .stencil import Stencil
from .._cholesky import cho_solve_lower


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
    ``e, e0 (S, 3)`` and ``along, across (S,)``: ``_model.energy.radial_blocks`` in planes."""
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


# -- the two-level preconditioner's coarse space on a grid: square blocks of b x b particles
# (``_layout.aggregates.grid_block``), so that restriction and prolongation are block sums and copies.

def _block_grid(st: Stencil, b: int) -> tuple[int, int]:
    return block_grid(st.rows, st.cols, b)


def _padded(st: Stencil, b: int, F, r0: int, c0: int):
    """``F (..., h, w)``, a window of the grid at ``(r0, c0)``, padded to ``(nI b, nJ b)``."""
    nI, nJ = _block_grid(st, b)
    lead = [(0, 0)] * (F.ndim - 2)
    return jnp.pad(F, lead + [(r0, nI * b - r0 - F.shape[-2]), (c0, nJ * b - c0 - F.shape[-1])])


def block_reduce(st: Stencil, b: int, F):
    """Block sums ``(..., nI, nJ)`` of a plane ``F (..., rows, cols)``."""
    nI, nJ = _block_grid(st, b)
    return _padded(st, b, F, 0, 0).reshape(F.shape[:-2] + (nI, b, nJ, b)).sum((-3, -1))


def coarse_matrix(st: Stencil, b: int, A, D, free):
    """The Galerkin matrix ``P^T H P`` (``3 count`` square) of ``_implicit.coarse`` on blocks.

    Args:
      A: ``(3, 3, S)`` PSD spring blocks.
      D: ``(3, 3, rows, cols)`` the diagonal blocks of ``H`` (``M/h^2``, the particle's
        springs, contact).
      free: ``(rows, cols)`` 1.0 on free particles.

    A spring joins two blocks whose offset ``(dI, dJ)`` is known from its family and
    position; block sums by offset class give ``H``'s coarse blocks without a scatter over
    springs.  The diagonal: ``sum free D`` less twice the springs inside a block.
    """
    nI, nJ = _block_grid(st, b)
    count = nI * nJ
    classes = {(0, 0): block_reduce(st, b, D * free)}
    for k, n, (r0, r1, c0, c1), (dr, dc) in _families(st):
        F = A[:, :, k:k + n].reshape((3, 3, r1 - r0, c1 - c0))
        F = _padded(st, b, F * (free[r0:r1, c0:c1] * free[r0 + dr:r1 + dr, c0 + dc:c1 + dc]), r0, c0)
        # a spring's block offset depends on its second end's place in its block only
        place = np.arange(b)
        dI, dJ = (place + dr) // b, (place + dc) // b
        ai, aj = np.unique(dI), np.unique(dJ)
        MI = (dI[None, :] == ai[:, None]).astype(F.dtype)
        MJ = (dJ[None, :] == aj[:, None]).astype(F.dtype)
        X = jnp.einsum("xyIrJc,ar,bc->abxyIJ", F.reshape((3, 3, nI, b, nJ, b)), MI, MJ)
        for u, a in enumerate(ai):
            for v, c in enumerate(aj):
                key = (int(a), int(c))
                Y = X[u, v] * (-2.0 if key == (0, 0) else -1.0)
                classes[key] = classes[key] + Y if key in classes else Y
    I, J = (g.reshape(-1) for g in np.meshgrid(np.arange(nI), np.arange(nJ), indexing="ij"))
    at, to, vals = [], [], []
    for (a, c), X in classes.items():
        X = X.reshape((3, 3, count))
        if (a, c) == (0, 0):
            at.append(I * nJ + J)
            to.append(I * nJ + J)
            vals.append(X)
            continue
        ok = (I + a >= 0) & (I + a < nI) & (J + c >= 0) & (J + c < nJ)
        src, dst = (I * nJ + J)[ok], ((I + a) * nJ + J + c)[ok]
        X = X[:, :, np.flatnonzero(ok)]
        at += [dst, src]  # the block and its mirror (A_s is symmetric)
        to += [src, dst]
        vals += [X, X]
    at, to = np.concatenate(at), np.concatenate(to)
    vals = jnp.concatenate(vals, axis=-1).transpose(2, 0, 1)
    Ac = jnp.zeros((count, 3, count, 3), A.dtype).at[at, :, to, :].add(vals).reshape(3 * count, 3 * count)
    empty = (block_reduce(st, b, free) == 0).reshape(-1).astype(A.dtype)  # a block of pins: identity
    return Ac + jnp.diag(jnp.repeat(empty, 3))


def coarse_correction(st: Stencil, b: int, factor, free):
    """``r -> P A_c^-1 P^T r`` on planes ``(3, rows, cols)``; ``free (1, rows, cols)``."""
    nI, nJ = _block_grid(st, b)

    def coarse(r):
        rc = block_reduce(st, b, r * free).transpose(1, 2, 0).reshape(-1)
        zc = cho_solve_lower(factor[0], rc).reshape(nI, nJ, 3).transpose(2, 0, 1)
        z = jnp.broadcast_to(zc[:, :, None, :, None], (3, nI, b, nJ, b)).reshape(3, nI * b, nJ * b)
        return z[:, :st.rows, :st.cols] * free

    return coarse
