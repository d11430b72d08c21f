"""Cholesky factor and solve of one matrix at a time under ``vmap`` (``sequential_vmap``),
for the dense Newton direction and the two-level preconditioner's coarse solve."""

from __future__ import annotations

import jax
from jax import lax


@jax.custom_batching.sequential_vmap
def lower_cholesky(A):
    """The lower Cholesky factor of ``A (n, n)`` (NaN if not SPD); batched one matrix after
    another (as ``_implicit.linsolve.dense_solve``: two of jaxlib's batched LAPACK kernels
    at once can deadlock on XLA:CPU's thread pool)."""
    return lax.linalg.cholesky(A, symmetrize_input=False)


@jax.custom_batching.sequential_vmap
def cho_solve_lower(L, b):
    """``A^-1 b`` from the lower Cholesky factor ``L (n, n)`` of ``A``; batched one matrix
    after another (as :func:`lower_cholesky`)."""
    return jax.scipy.linalg.cho_solve((L, True), b)
