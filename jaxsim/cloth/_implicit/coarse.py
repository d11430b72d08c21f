"""A two-level preconditioner for the Newton step's CG: block Jacobi around a coarse solve.

Block Jacobi (``_implicit.hessian.block_jacobi``) removes the stiffness of each particle's own
springs, but not the smooth, cloth-wide modes.  On stiff, light cloth (``k h^2 / m`` in
the thousands) those modes need hundreds of CG iterations per Newton iteration.

Here the particles are grouped into at most ``MAX_AGGREGATES`` aggregates: square
blocks of the particle grid on a grid scene (``grid_block``, ``block_ids``; restriction,
prolongation and the Galerkin product then run on planes, ``_layout.planes``), else the cells of
a voxel grid over the rest shape (``aggregate``).  The prolongation ``P`` copies an
aggregate's 3-vector to each of its free particles (piecewise-constant aggregation).
The coarse matrix is the Galerkin product ``A_c = P^T A P`` of the preconditioning
operator ``A = M/h^2 + sum_s A_s (+ contact)``, assembled from the same PSD blocks and
factored by dense Cholesky once per Newton iteration.  ``A_c`` is at most 192 x 192.

One application is a symmetric two-level cycle (Jacobi, coarse correction, Jacobi):

    z = D^-1 r;  z += P A_c^-1 P^T (r - A z);  z += D^-1 (r - A z)

It is symmetric positive definite: ``A_c`` is SPD when the blocks are PSD and the masses
positive, and block Jacobi is a convergent smoother because ``2D - A = M/h^2 +
sum_s [[A_s, A_s], [A_s, A_s]]`` is positive definite.  Each application costs two
extra operator products; it pays where CG needs many iterations (see the README's
scene C) and not on soft cloth, hence ``CG(preconditioner=Jacobi())`` by
default.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax
from .._cholesky import cho_solve_lower, lower_cholesky


#: A float64 coarse matrix is factored in float32, shifted where needed so that an upper
#: bound on its condition number times float32's epsilon stays below this (``cholesky``).
#: Scene C at a state 10 steps in (that product, the bound's): 32x32 k = 1e5 0.058, 0.083;
#: 64x64 k = 1e5 0.12, 0.15 (no shift); 32x32 k = 1e6 0.31, 0.83 (shifted).
FLOAT32_FACTOR_LIMIT = 0.5


def cholesky(Ac, lam_min):
    """``(L, True)``: a lower Cholesky factor of the SPD coarse matrix ``Ac (n, n)``, for
    ``jax.scipy.linalg.cho_solve``, in ``Ac``'s dtype.

    A float64 ``Ac`` is factored in float32, after adding ``sigma I`` with the least
    ``sigma >= 0`` that brings Gershgorin's bound on its largest eigenvalue over
    ``lam_min + sigma`` down to ``FLOAT32_FACTOR_LIMIT / eps32`` (``lam_min``: ``()``, a
    lower bound on ``Ac``'s smallest eigenvalue, the least free mass of an aggregate over
    ``h^2``).  The factor exists, and the preconditioner stays symmetric positive
    definite: it is the exact factor of a nearby SPD matrix, and its triangular solves run
    in float64.  On XLA:CPU the float64 factor cost more than its LAPACK call (copies, the
    failure check's select): C 32x32 k = 1e5 about 4 ms of 30 per step (README,
    "Two-level preconditioner").  A float64 fallback chosen at run time instead of the
    shift (``lax.cond`` or a ``while_loop``) hung ``batch_rollout`` under ``vmap`` on
    XLA:CPU: two batched LAPACK calls at once (``linsolve.dense_solve``).
    """
    if Ac.dtype != jnp.float64:
        return lower_cholesky(Ac), True
    eps = jnp.finfo(jnp.float32).eps
    top = jnp.max(jnp.sum(jnp.abs(Ac), axis=1))  # >= the largest eigenvalue (Gershgorin)
    shift = jnp.maximum(top * eps / FLOAT32_FACTOR_LIMIT - lam_min, 0.0)  # 0 unless very stiff
    n = Ac.shape[0]
    L = lower_cholesky((Ac + shift * jnp.eye(n, dtype=Ac.dtype)).astype(jnp.float32))
    return L.astype(Ac.dtype), True


def coarse_factor(ids, count: int, springs, A, diag, free, lam_min):
    """Cholesky factor of :func:`coarse_matrix` (:func:`cholesky`)."""
    return cholesky(coarse_matrix(ids, count, springs, A, diag, free), lam_min)


def least_mass(aggregate_mass, h):
    """``()`` the least free mass of an aggregate over ``h^2`` (1 for an aggregate of pins,
    whose coarse rows are the identity): a lower bound on the coarse matrix's eigenvalues.

    ``aggregate_mass``: each aggregate's free mass, any shape (``segment_sum`` over the
    aggregates, or ``_layout.planes.block_reduce`` on a grid)."""
    m = aggregate_mass / h**2
    return jnp.min(jnp.where(m > 0, m, 1.0))


def coarse_matrix(ids, count: int, springs, A, diag, free):
    """The Galerkin coarse matrix ``P^T A P`` (``3 count`` square).

    Args:
      ids: ``(N,)`` int32 aggregate of each particle.
      springs: ``(S, 2)`` spring ends.
      A: ``(S, 3, 3)`` PSD spring blocks.
      diag: ``(N, 3, 3)`` per-particle blocks (``M/h^2`` plus contact).
      free: ``(N,)`` 1.0 for free particles, 0.0 for pinned ones (rows of ``P`` are 0 there).
    """
    i, j = springs[:, 0], springs[:, 1]
    ai, aj = ids[i], ids[j]
    wi, wj = free[i][:, None, None], free[j][:, None, None]
    per_aggregate = jax.ops.segment_sum(free[:, None, None] * diag, ids, count)  # (count, 3, 3)
    Ac = jnp.eye(count, dtype=A.dtype)[:, :, None, None] * per_aggregate[:, None]
    Ac = Ac.at[ai, ai].add(wi * A).at[aj, aj].add(wj * A).at[ai, aj].add(-wi * wj * A).at[aj, ai].add(-wi * wj * A)
    Ac = Ac.transpose(0, 2, 1, 3).reshape(3 * count, 3 * count)
    # an aggregate of pins only has no coarse unknowns: identity there
    empty = (jax.ops.segment_sum(free, ids, count) == 0).astype(A.dtype)
    return Ac + jnp.diag(jnp.repeat(empty, 3))


def coarse_correction(ids, count: int, factor, free):
    """``r -> P A_c^-1 P^T r`` on ``(N, 3)`` vectors; ``free (N, 1)``."""

    def coarse(r):
        rc = jax.ops.segment_sum(r * free, ids, count).reshape(-1)
        zc = cho_solve_lower(factor[0], rc).reshape(count, 3)
        return zc[ids] * free

    return coarse


def two_level(coarse, jacobi, operator):
    """The symmetric two-level cycle of the module doc, as ``r -> z`` in CG's layout.

    Args:
      coarse: ``r -> P A_c^-1 P^T r`` (:func:`coarse_correction`, or ``_layout.planes.coarse_correction``).
      jacobi: ``r -> D^-1 r`` (identity on pins).
      operator: ``v -> A v`` restricted to the free particles (identity on pins).
    """

    def apply(r):
        # the two corrections as a loop of two stages, so that each operator product reads
        # a materialised z: written out, XLA:CPU fused the computation of z into each of the
        # second product's slices and recomputed it there (C 32x32, planes, float64: 129
        # against 51 us per application; README "Two-level preconditioner")
        def stage(k, z):
            return z + lax.cond(k == 0, coarse, jacobi, r - operator(z))

        return lax.fori_loop(0, 2, stage, jacobi(r))

    return apply
