"""Newton's search direction (lab Algorithm 2's linear solve): the Hessian's parts at an
iterate, and a dense or PCG solve of each Hessian that ``project_psd`` tries in turn."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
from jax import lax

from ..._dataclass import pytree_dataclass
from .._model import energy as en
from .linsolve import dense_solve, lu_solve, pcg
from .setup import NewtonSetup
from .._model.aero import blocks as aero_blocks
from .._rank_one import RankOne, combine
from .._self.terms import blocks as pair_blocks

#: ``project_psd="auto"``: when the exact Hessian is not positive definite, the direction is
#: first retried on the exact Hessian plus this many times the inertia term ``M / h^2``
#: (a Levenberg-Marquardt shift in the mass metric, which keeps the springs' curvature),
#: and only if that is still indefinite on the Hessian with every block clamped.  On scene C
#: k = 1e5 (float64) the clamped Hessian alone left Newton creeping for over 30 iterations of
#: one step at a relative gradient of 1e-6-1e-5; see docs/cloth.md, stiff cloth.
SHIFT = 1.0


@pytree_dataclass
class Direction:
    """One solve for a Newton direction.

    Attributes:
      dx: ``(N, 3)`` the direction (m).
      cg: ``()`` int32 PCG iterations (0 for Cholesky), summed over the Hessians tried.
      res: ``()`` relative residual of the solve (``inf`` if it broke down).
      indefinite: ``()`` bool, the solve found its Hessian indefinite; ``None`` on the
        direction chosen, whose ``hessian`` says which it is.
      hessian: ``()`` int32 which Hessian gave ``dx`` (index into ``trace.HESSIANS``).
    """

    dx: jax.Array
    cg: jax.Array
    res: jax.Array
    indefinite: jax.Array | None
    hessian: jax.Array


@dataclasses.dataclass(frozen=True)
class HessianParts:
    """The Hessian's parts at one iterate, shared by every direction of the iteration.

    Attributes:
      exact: the exact spring blocks; ``psd``: each projected PSD (``(S, 3, 3)``, or
        planes for PCG on a grid: ``hessian``).
      contact: the PSD contact blocks in PCG's layout (``(N, 3, 3)`` dense), or ``None``.
      precond: the SPD preconditioner ``r -> z`` (``None`` for Cholesky).
      pairs: the rank-one PSD blocks of the self-contact pairs and the wind's drag
        (``_rank_one.RankOne``), or ``None``.
    """

    exact: jax.Array
    psd: jax.Array
    contact: jax.Array | None
    precond: Callable | None
    pairs: RankOne | None = None


def _safe_ratio(num, den):
    r = num / jnp.maximum(den, jnp.finfo(num.dtype).tiny)
    return jnp.where(jnp.isfinite(r), r, jnp.inf)


def hessian_parts(sv: NewtonSetup, w, terms, pairs=None) -> HessianParts:
    """:class:`HessianParts` at ``w`` from its spring ``terms`` (and self-contact ``pairs``)."""
    ops = sv.ops
    A_exact = ops.blocks(w, terms, project_psd=False)
    A_psd = ops.blocks(w, terms, project_psd=True)
    C, C_cg = ops.contact(w)
    P = None
    if sv.p.selfc is not None:
        p = sv.at(pairs)
        P = pair_blocks(p.selfc, p.positions(w), sv.free)
    if sv.p.aero is not None:
        P = combine(P, aero_blocks(sv.p.aero, sv.p.displacement(w), sv.p.h, sv.free))
    if sv.dense:
        return HessianParts(A_exact, A_psd, C, None, P)
    return HessianParts(A_exact, A_psd, C_cg, ops.preconditioner(A_psd, C, C_cg, P), P)


def dense(sv: NewtonSetup, b, H, indefinite=False) -> Direction:
    """Cholesky (LU with ``indefinite=True``) on ``H (3N, 3N)`` with pinned rows and
    columns replaced by the identity; Cholesky of an indefinite ``H`` gives non-finite values."""
    f3 = sv.free3
    H = H * f3[:, None] * f3[None, :] + jnp.diag(1.0 - f3)
    dx = lu_solve(H, b.reshape(-1)) if indefinite else dense_solve(H, b.reshape(-1))
    res = _safe_ratio(jnp.linalg.norm(H @ dx - b.reshape(-1)), jnp.linalg.norm(b))
    return Direction(dx.reshape(sv.N, 3), jnp.int32(0), res, ~jnp.all(jnp.isfinite(dx)), jnp.int32(0))


def assembled(sv: NewtonSetup, A, C, inertia=1.0, pairs: RankOne | None = None):
    """The dense Hessian ``(3N, 3N)``: spring blocks ``A``, ``inertia M/h^2``, contact ``C``
    and the self-contact ``pairs``."""
    c, h, N = sv.p.cloth, sv.p.h, sv.N
    H = en.assemble(c, A) + jnp.diag(inertia * jnp.repeat(c.mass, 3) / h**2)
    if C is not None:
        eye = jnp.eye(N, dtype=C.dtype)
        H = H + (eye[:, None, :, None] * C[:, :, None, :]).reshape(3 * N, 3 * N)
    if pairs is not None:
        H = H + pairs.dense(N)
    return H


def cg(sv: NewtonSetup, b, hvp, guess, Minv, tol, indefinite=False) -> Direction:
    """PCG on ``ops.restricted(hvp)`` in its layout; ``b``, ``guess`` and ``dx`` ``(N, 3)``;
    ``indefinite``: a bool or a traced ``()`` bool (``linsolve.pcg``)."""
    ops = sv.ops
    dx, k, res, broke = pcg(ops.restricted(hvp), ops.to_cg(b), ops.to_cg(guess * sv.free), Minv, tol=tol,
                            max_iters=sv.linear.max_iters, indefinite=indefinite)
    return Direction(ops.from_cg(dx), k, jnp.where(jnp.isfinite(res), res, jnp.inf), broke, jnp.int32(0))


def _chosen(d: Direction) -> Direction:
    """``d`` as the iteration's direction: a setting with one Hessian has nothing to retry."""
    return dataclasses.replace(d, indefinite=None)


#: ``project_psd="auto"``'s Hessians, by their index in ``trace.HESSIANS``: the exact
#: spring blocks, the same plus ``SHIFT M / h^2``, every block clamped PSD, and the exact
#: blocks solved through negative curvature for a stationary point.
EXACT, SHIFTED, CLAMPED, STATIONARY = range(4)


def _retries(first: Direction, solve) -> Direction:
    """``first`` (a solve on the exact Hessian), or where it found that Hessian indefinite
    the first definite of ``solve(SHIFTED)`` and ``solve(CLAMPED)`` (the last regardless):
    one bounded loop around one solve whose Hessian is chosen by the traced index, so one
    copy of the retried solver is compiled, not one a Hessian, and under ``vmap`` a retry
    runs only while some element needs it.  ``hessian`` says which Hessian gave ``dx``;
    the PCG iterations of every solve run are summed."""
    def body(c):
        k, prev = c
        d = solve(k + 1)
        return k + 1, dataclasses.replace(d, cg=prev.cg + d.cg)

    def retry():
        k, d = lax.while_loop(lambda c: c[1].indefinite & (c[0] < CLAMPED), body, (jnp.int32(EXACT), first))
        return Direction(d.dx, d.cg, d.res, None, k)

    return lax.cond(first.indefinite, retry, lambda: _chosen(first))


def _auto_hessian(parts: HessianParts, k, dtype):
    """``(spring blocks, inertia factor)`` of ``"auto"``'s retried Hessian ``k`` (traced)."""
    return jnp.where(k == CLAMPED, parts.psd, parts.exact), jnp.where(k == SHIFTED, 1.0 + SHIFT, 1.0).astype(dtype)


def auto_cg(sv: NewtonSetup, b, parts: HessianParts, guess, tol, stationary=False) -> Direction:
    """``project_psd="auto"`` by PCG: the exact Hessian, solved through negative curvature
    for a stationary point where ``stationary`` (a ``()`` bool), else the first definite
    of exact, shifted and clamped."""
    def solve(k):
        A, inertia = _auto_hessian(parts, k, sv.dtype)
        return cg(sv, b, sv.ops.hvp(A, parts.contact, inertia, parts.pairs), guess, parts.precond, tol)

    first = cg(sv, b, sv.ops.hvp(parts.exact, parts.contact, pairs=parts.pairs), guess, parts.precond, tol,
               indefinite=stationary)
    first = dataclasses.replace(first, indefinite=first.indefinite & ~stationary,
                                hessian=jnp.where(stationary, STATIONARY, EXACT).astype(jnp.int32))
    return _retries(first, solve)


def auto_dense(sv: NewtonSetup, b, parts: HessianParts) -> Direction:
    """``project_psd="auto"`` by Cholesky: the first definite of exact, shifted and clamped."""
    def solve(k):
        A, inertia = _auto_hessian(parts, k, sv.dtype)
        return dense(sv, b, assembled(sv, A, parts.contact, inertia, parts.pairs))

    return _retries(dense(sv, b, assembled(sv, parts.exact, parts.contact, pairs=parts.pairs)), solve)


def stationary(sv: NewtonSetup, b, parts: HessianParts) -> Direction:
    """The exact Hessian solved densely through negative curvature (LU; ``hessian`` 3: a
    stationary point).  PCG takes this solve in :func:`auto_cg`."""
    d = dense(sv, b, assembled(sv, parts.exact, parts.contact, pairs=parts.pairs), indefinite=True)
    return dataclasses.replace(d, indefinite=None, hessian=jnp.int32(STATIONARY))


def minimising(sv: NewtonSetup, w, b, parts: HessianParts, guess, tol) -> Direction:
    """The Newton direction on the Hessian that ``integ.project_psd`` picks (the first
    definite one of exact, shifted and clamped with ``"auto"``)."""
    projection, ops = sv.integ.project_psd, sv.ops
    if sv.dense and projection is False:
        return _chosen(dense(sv, b, jax.hessian(sv.objective)(w).reshape(3 * sv.N, 3 * sv.N)))
    A_psd, C, Minv = parts.psd, parts.contact, parts.precond
    if sv.dense:
        if projection is True:
            return _chosen(dense(sv, b, assembled(sv, A_psd, C, pairs=parts.pairs)))
        return auto_dense(sv, b, parts)
    if projection is True:
        return _chosen(cg(sv, b, ops.hvp(A_psd, C, pairs=parts.pairs), guess, Minv, tol))
    if projection is False:  # the exact Hessian, through the autodiff Hessian-vector product
        hvp = lambda v: ops.to_cg(jax.jvp(sv.grad, (w,), (ops.from_cg(v),))[1])  # noqa: E731
        return _chosen(cg(sv, b, hvp, guess, Minv, tol))
    return auto_cg(sv, b, parts, guess, tol)
