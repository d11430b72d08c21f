"""The Newton step's Hessian for PCG: spring blocks, operator and preconditioners.

The Hessian of the step's objective is ``M/h^2 + sum_s [[A_s, -A_s], [-A_s, A_s]]`` (plus
per-particle contact blocks ``C``), never formed: PCG applies it through the per-spring
3x3 blocks ``A_s`` (``_energy.radial_blocks``).  On a grid scene everything PCG touches
is in planes (``_planes``): vectors ``(3, rows, cols)``, blocks ``(3, 3, S)``; elsewhere
``(N, 3)`` and ``(S, 3, 3)``.  :class:`HessianOps` hides which.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from .._fusion import materialized
from . import _contact as ct
from . import _planes as pl
from . import _problem as pr
from ._coarse import cholesky, coarse_correction, coarse_factor, least_mass, two_level
from ._linear import TwoLevel
from ._linsolve import block_inverse
from ._scene import spring_diff, spring_sum
from ._vec import matvec


def particle_blocks(p: pr.StepProblem, C=None):
    """``(N, 3, 3)`` per-particle Hessian blocks: ``M/h^2`` plus the contact blocks ``C``."""
    c = p.cloth
    dtype = p.x0.dtype
    D = jnp.broadcast_to((c.mass / p.h**2)[:, None, None] * jnp.eye(3, dtype=dtype), (c.num_particles, 3, 3))
    return D if C is None else D + C


def block_jacobi(p: pr.StepProblem, A, C=None):
    """``r -> D^{-1} r`` with ``D`` the 3x3 diagonal blocks of ``M/h^2 + sum_s A_s (+ C)``
    (identity on pins); ``A (S, 3, 3)``, ``C (N, 3, 3)`` per-particle (contact) blocks."""
    D = spring_sum(p.cloth, A, signed=False) + particle_blocks(p, C)
    D = jnp.where(p.free[:, :, None] > 0, D, jnp.broadcast_to(jnp.eye(3, dtype=A.dtype), D.shape))
    Dinv = block_inverse(D)
    return lambda r: matvec(Dinv, r)


class HessianOps:
    """The Hessian's pieces in PCG's layout for one step problem (built while tracing).

    Args:
      p: the step problem.
      planar: run PCG on planes (needs ``p.cloth.stencil``).
      preconditioner: ``CG.preconditioner`` (``Jacobi()`` or ``TwoLevel()``), ``None`` for Cholesky.
    """

    def __init__(self, p: pr.StepProblem, planar: bool, preconditioner):
        c = p.cloth
        self.p, self.two_level = p, isinstance(preconditioner, TwoLevel)
        self.st = c.stencil if planar else None
        free = p.free
        if self.st is None:
            self.free, self.m = free, c.mass[:, None]
        else:
            self.free = pl.particle_planes(self.st, free[:, 0])[None]
            self.m = pl.particle_planes(self.st, c.mass)[None]
        self.lam_min = None  # the two-level coarse matrix's eigenvalue bound, once per step
        if self.two_level:
            if self.st is not None and c.coarse_block:
                agg = pl.block_reduce(self.st, c.coarse_block, self.m[0] * self.free[0])
            else:
                agg = jax.ops.segment_sum(c.mass * free[:, 0], c.aggregates, c.num_aggregates)
            self.lam_min = least_mass(agg, p.h)

    def to_cg(self, v):
        """``(N, 3)`` to PCG's layout."""
        return v if self.st is None else pl.to_planes(self.st, v)

    def from_cg(self, v):
        """PCG's layout to ``(N, 3)``."""
        return v if self.st is None else pl.from_planes(v)

    def restricted(self, hvp):
        """``v -> hvp(v)`` on the free particles, the identity on pins."""
        return lambda v: hvp(v * self.free) * self.free + (1.0 - self.free) * v

    def blocks(self, w, terms, *, project_psd: bool):
        """The spring blocks at ``w`` from its ``terms`` (``_problem.SpringTerms``)."""
        if self.st is None:
            return pr.blocks(w, self.p, project_psd=project_psd, terms=terms)
        p = self.p
        e0, doh = (p.e0, p.d_over_h) if p.e0 is not None else (None, None)
        return pl.radial_blocks(terms.e, terms.along, terms.across, e0, doh, project_psd=project_psd)

    def contact(self, w):
        """``(C (N, 3, 3), C in PCG's layout)``, the PSD contact blocks at ``w``, or ``(None, None)``."""
        p = self.p
        if p.contact is None:
            return None, None
        C = ct.blocks(p.displacement(w), p.x0, p.cloth, p.contact, p.free)
        return C, (C if self.st is None else pl.particle_planes(self.st, C))

    def hvp(self, A, C_cg, inertia=1.0):
        """``v -> (inertia M/h^2 + sum_s A_s + C) v`` (unrestricted)."""
        h = self.p.h

        def apply(v):
            if self.st is None:
                out = spring_sum(self.p.cloth, matvec(A, spring_diff(self.p.cloth, v)))
            else:
                out = pl.operator(self.st, A, v)
            out = out + inertia * self.m / h**2 * v
            if C_cg is None:
                return out
            return out + (matvec(C_cg, v) if self.st is None else pl.matvec(C_cg, v))

        return apply

    def diagonal(self, A_psd, C_cg):
        """The diagonal blocks of ``M/h^2 + sum_s A_s (+ C)``: ``(3, 3, rows, cols)`` on planes."""
        eye = jnp.eye(3, dtype=A_psd.dtype)[:, :, None, None]
        D = pl.block_sums(self.st, A_psd) + eye * (self.m[0] / self.p.h**2)
        return D if C_cg is None else D + C_cg

    def jacobi(self, A_psd, C_cg, D=None):
        """Block Jacobi: ``r -> D^{-1} r`` (identity on pins); ``D`` from :meth:`diagonal`."""
        if self.st is None:
            return block_jacobi(self.p, A_psd, C_cg)
        D = self.diagonal(A_psd, C_cg) if D is None else D
        eye = jnp.eye(3, dtype=A_psd.dtype)[:, :, None, None]
        Dinv = block_inverse(jnp.where(self.free[0] > 0, D, eye), planar=True)
        return functools.partial(pl.matvec, Dinv)

    def preconditioner(self, A_psd, C, C_cg):
        """Block Jacobi, or the two-level cycle of ``_coarse`` around it (SPD)."""
        # the diagonal blocks written once: the block inverse (and the coarse matrix) read
        # every entry several times (``_fusion``)
        D = None if self.st is None else materialized(self.diagonal(A_psd, C_cg))
        jacobi = self.jacobi(A_psd, C_cg, D)
        if not self.two_level:
            return jacobi
        p, c = self.p, self.p.cloth
        if self.st is not None and c.coarse_block:  # blocks of the grid: no scatter, no gather
            b = c.coarse_block
            factor = cholesky(pl.coarse_matrix(self.st, b, A_psd, D, self.free[0]), self.lam_min)
            coarse = pl.coarse_correction(self.st, b, factor, self.free)
        else:
            A_aos = A_psd if self.st is None else A_psd.transpose(2, 0, 1)
            factor = coarse_factor(c.aggregates, c.num_aggregates, c.springs, A_aos, particle_blocks(p, C),
                                   p.free[:, 0], self.lam_min)
            coarse = coarse_correction(c.aggregates, c.num_aggregates, factor, p.free, self.to_cg, self.from_cg)
        return two_level(coarse, jacobi, self.restricted(self.hvp(A_psd, C_cg)))
