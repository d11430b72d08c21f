"""The derivative of an implicit step by the implicit function theorem at its solution.

Nothing is differentiated through the Newton, line-search or CG loops: the converged
unknown ``w*`` (the deviation from the prediction of inertia and gravity, ``_implicit.problem`` module doc)
solves ``F(w*, p) = 0`` and ``dw*/dp = -J^{-1} dF/dp`` with one linear solve with the
exact Hessian.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax import lax

from . import contact as ct
from . import problem as pr
from .linsolve import lu_solve, pcg
from .hessian import block_jacobi
from .._linear import Cholesky


def stationarity(w, p: pr.StepProblem):
    """Root function in the free unknowns ``w (N, 3)``; a pinned particle's entry is
    ``w - w_pin`` (``StepProblem.pinned_at``: ``-y`` for a pin that stays, ``y`` being
    ``StepProblem.prediction``), 0 at the solution.

    ``F(w) = P grad g(P w - (1 - P) y) + (1 - P) (w + y)``: its Jacobian
    ``P H P + (1 - P)`` is symmetric.
    """
    free = p.free > 0
    pinned_at = p.pinned_at
    return jnp.where(free, jax.grad(pr.incremental_potential)(jnp.where(free, w, pinned_at), p), w - pinned_at)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def solution(integ, w_star, p: pr.StepProblem):
    """Identity on the converged ``w_star (N, 3)``; its derivative is the implicit-function one.

    The tangent solve goes through ``lax.custom_linear_solve`` (symmetric), so reverse
    mode transposes it as the same solve.
    """
    return w_star


@solution.defjvp
def _solution_jvp(integ, primals, tangents):
    w_star, p = primals
    _, p_dot = tangents
    rhs = jax.jvp(lambda q: stationarity(w_star, q), (p,), (p_dot,))[1]

    def matvec(t):
        return jax.jvp(lambda w: stationarity(w, p), (w_star,), (t,))[1]

    N = p.cloth.num_particles
    lin = integ.linear(N)
    if isinstance(lin, Cholesky):
        def solve(mv, b):
            eye = jnp.eye(3 * N, dtype=b.dtype).reshape(3 * N, N, 3)
            A = jax.vmap(mv)(eye).reshape(3 * N, 3 * N)
            return lu_solve(A, b.reshape(-1)).reshape(N, 3)
    else:
        C = None if p.contact is None else ct.blocks(p.displacement(w_star), p.x0, p.cloth, p.contact, p.free)
        Minv = block_jacobi(p, pr.blocks(w_star, p, project_psd=True), C)

        def solve(mv, b):
            # the solution may be a stationary point where the Hessian is indefinite
            return pcg(mv, b, jnp.zeros_like(b), Minv, tol=lin.tol, max_iters=lin.max_iters,
                       indefinite=True)[0]

    dw = lax.custom_linear_solve(matvec, rhs, solve, symmetric=True)
    return w_star, -dw
