"""Linear solves for the Newton step: dense Cholesky, and matrix-free block-Jacobi PCG."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax


@jax.custom_batching.sequential_vmap
def dense_solve(H, b):
    """Solve ``H x = b`` with Cholesky (``H`` SPD, ``(n, n)``); NaN if ``H`` is not SPD.

    Batched (under ``vmap``) one matrix after another, as :func:`lu_solve`: jaxlib 0.10's
    batched LAPACK kernels split their batch over XLA:CPU's intra-op thread pool and
    block until it is done, so two of them that the program runs at once (the
    alternatives of a batched ``lax.cond``, which ``vmap`` evaluates both of) can take
    every pool thread and wait for each other forever (``docs/notebook.md``, "A batched
    rollout that never returned").
    """
    c = jax.scipy.linalg.cho_factor(H, lower=True)
    return jax.scipy.linalg.cho_solve(c, b)


@jax.custom_batching.sequential_vmap
def lu_solve(A, b):
    """Solve ``A x = b`` by LU with partial pivoting (``A`` nonsingular, ``(n, n)``);
    batched one matrix after another (:func:`dense_solve`)."""
    return jnp.linalg.solve(A, b)


def pcg(apply_A, b, x0, apply_Minv, *, tol, max_iters: int, indefinite: bool = False):
    """Preconditioned conjugate gradients (Hestenes & Stiefel; Shewchuk 1994, B3).

    Written here because ``jax.scipy.sparse.linalg.cg`` reports no iteration count.
    Stops when ``|r| <= tol * |b|``.  A non-positive curvature ``p.Ap <= 0`` (an
    indefinite operator) stops the loop and keeps the last iterate; with ``indefinite=True``
    only ``p.Ap = 0`` does (CG on a symmetric indefinite, nonsingular operator, for the
    stationary point rather than the minimiser of ``x.Ax/2 - b.x``); ``indefinite`` may be a
    traced ``()`` bool.

    Args:
      apply_A, apply_Minv: linear maps on arrays shaped like ``b``.
      b, x0: right-hand side and initial guess (any shape).

    Returns:
      ``(x, iterations, relative_residual, broke)``; ``broke`` is True when a
      non-positive curvature ``p.Ap <= 0`` was met (the operator is not positive definite;
      with ``indefinite=True``: a zero or non-finite ``p.Ap``).
    """
    # a dot rather than sum(u * v): XLA:CPU emits the product of two (N, 3) operands as its
    # own loop before a tree reduction; for N = 1024, 7.5 against 1.6 us per dot in a loop
    # (benchmarks/cloth_profile.py)
    dot = lambda u, v: jnp.vdot(u.reshape(-1), v.reshape(-1))  # noqa: E731
    bnorm = jnp.sqrt(dot(b, b))
    thresh = tol * bnorm
    r = b - apply_A(x0)
    z = apply_Minv(r)
    rz = dot(r, z)
    state = (x0, r, z, z, rz, jnp.int32(0), jnp.array(False))

    def cond(s):
        x, r, z, p, rz, k, broke = s
        return (k < max_iters) & (jnp.sqrt(dot(r, r)) > thresh) & ~broke

    def body(s):
        x, r, z, p, rz, k, broke = s
        Ap = apply_A(p)
        pAp = dot(p, Ap)
        if isinstance(indefinite, bool):
            broke = ~(pAp > 0) if not indefinite else ~(jnp.abs(pAp) > 0)
        else:  # chosen at run time (``_implicit.direction``'s one loop over Hessians)
            broke = ~(jnp.where(indefinite, jnp.abs(pAp), pAp) > 0)
        alpha = jnp.where(broke, 0.0, rz / jnp.where(broke, 1.0, pAp))
        x = x + alpha * p
        r = r - alpha * Ap
        z = apply_Minv(r)
        rz_new = dot(r, z)
        beta = jnp.where(broke, 0.0, rz_new / jnp.where(rz == 0, 1.0, rz))
        p = z + beta * p
        return x, r, z, p, rz_new, k + 1, broke

    x, r, _, _, _, k, broke = lax.while_loop(cond, body, state)
    rel = jnp.sqrt(dot(r, r)) / jnp.where(bnorm > 0, bnorm, 1.0)
    return x, k, rel, broke


def block_inverse(blocks, planar: bool = False):
    """Inverses of SPD 3x3 blocks (the block-Jacobi preconditioner): ``(N, 3, 3)``, or
    ``(3, 3, ...)`` with ``planar`` (``_layout.planes``).

    Closed form (adjugate over determinant), elementwise over the batch: much faster
    on CPU than a batched LU for 3x3 blocks.
    """
    a = (lambda i, j: blocks[i, j]) if planar else (lambda i, j: blocks[..., i, j])  # noqa: E731
    inner, outer = (0, 0) if planar else (-1, -2)
    c00 = a(1, 1) * a(2, 2) - a(1, 2) * a(2, 1)
    c01 = a(1, 2) * a(2, 0) - a(1, 0) * a(2, 2)
    c02 = a(1, 0) * a(2, 1) - a(1, 1) * a(2, 0)
    det = a(0, 0) * c00 + a(0, 1) * c01 + a(0, 2) * c02
    adj = jnp.stack([
        jnp.stack([c00, a(0, 2) * a(2, 1) - a(0, 1) * a(2, 2), a(0, 1) * a(1, 2) - a(0, 2) * a(1, 1)], inner),
        jnp.stack([c01, a(0, 0) * a(2, 2) - a(0, 2) * a(2, 0), a(0, 2) * a(1, 0) - a(0, 0) * a(1, 2)], inner),
        jnp.stack([c02, a(0, 1) * a(2, 0) - a(0, 0) * a(2, 1), a(0, 0) * a(1, 1) - a(0, 1) * a(1, 0)], inner),
    ], outer)
    return adj / (det if planar else det[..., None, None])
