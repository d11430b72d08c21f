"""The Newton step's Hessian for PCG: spring blocks, operator and preconditioners.

The Hessian of the step's objective is ``M/h^2 + sum_s [[A_s, -A_s], [-A_s, A_s]]`` (plus
per-particle contact blocks ``C``), never formed: PCG applies it through the per-spring
3x3 blocks ``A_s`` (``_model.energy.radial_blocks``).  On a grid scene (``PlanarLayout``)
everything PCG touches is in planes (``_layout.planes``): vectors ``(3, rows, cols)``, blocks
``(3, 3, S)``; elsewhere ``(N, 3)`` and ``(S, 3, 3)``.  :class:`HessianOps` is the one
interface, with an implementation for each.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..._fusion import materialized
from . import contact as ct
from .._layout import planes as pl
from . import problem as pr
from .coarse import cholesky, coarse_correction, coarse_factor, least_mass, two_level
from .._layout import PlanarLayout
from .._linear import CG, TwoLevel
from .linsolve import block_inverse
from .._vec import matvec


def particle_blocks(p: pr.StepProblem, C=None):
    """``(N, 3, 3)`` per-particle Hessian blocks: ``M/h^2`` plus the contact blocks ``C``."""
    c = p.cloth
    dtype = p.x0.dtype
    D = jnp.broadcast_to((c.mass / p.h**2)[:, None, None] * jnp.eye(3, dtype=dtype), (c.num_particles, 3, 3))
    return D if C is None else D + C


def block_jacobi(p: pr.StepProblem, A, C=None):
    """``r -> D^{-1} r`` with ``D`` the 3x3 diagonal blocks of ``M/h^2 + sum_s A_s (+ C)``
    (identity on pins); ``A (S, 3, 3)``, ``C (N, 3, 3)`` per-particle (contact) blocks."""
    D = p.sum(A, signed=False) + particle_blocks(p, C)
    D = jnp.where(p.free[:, :, None] > 0, D, jnp.broadcast_to(jnp.eye(3, dtype=A.dtype), D.shape))
    Dinv = block_inverse(D)
    return lambda r: matvec(Dinv, r)


class HessianOps:
    """The Hessian's pieces in PCG's layout for one step problem (built while tracing).

    One interface, two implementations: :class:`ParticleOps` (``(N, 3)`` vectors,
    ``(S, 3, 3)`` blocks) and :class:`PlaneOps` (planes, on a ``PlanarLayout``); pick
    with :func:`hessian_ops`.

    Args:
      p: the step problem.
      preconditioner: ``CG.preconditioner`` (``Jacobi()`` or ``TwoLevel()``), ``None`` for Cholesky.
    """

    def __init__(self, p: pr.StepProblem, preconditioner):
        self.p, self.two_level = p, isinstance(preconditioner, TwoLevel)
        self.free, self.m = self.column(p.free), self.column(p.cloth.mass[:, None])
        self.lam_min = None  # the two-level coarse matrix's eigenvalue bound, once per step
        if self.two_level:
            self.lam_min = least_mass(self.aggregate_mass(), p.h)

    # the layout: implemented by each subclass
    def column(self, a):
        """A per-particle scalar ``(N, 1)``, shaped to broadcast against PCG's vectors."""
        raise NotImplementedError

    def per_particle(self, C):
        """Per-particle 3x3 blocks ``(N, 3, 3)`` in PCG's layout."""
        raise NotImplementedError

    def to_cg(self, v):
        """``(N, 3)`` to PCG's layout."""
        raise NotImplementedError

    def from_cg(self, v):
        """PCG's layout to ``(N, 3)``."""
        raise NotImplementedError

    def blocks(self, w, terms, *, project_psd: bool):
        """The spring blocks at ``w`` from its ``terms`` (``_implicit.problem.SpringTerms``)."""
        raise NotImplementedError

    def springs(self, A, v):
        """``v -> sum_s A_s`` applied to ``v`` (the springs' share of the operator)."""
        raise NotImplementedError

    def matvec(self, C, v):
        """Per-particle 3x3 blocks ``C`` applied to ``v``, both in PCG's layout."""
        raise NotImplementedError

    def aggregate_mass(self):
        """Each aggregate's free mass (kg), for ``_implicit.coarse.least_mass``."""
        raise NotImplementedError

    def jacobi(self, A_psd, C, C_cg):
        """``(jacobi, D)``: block Jacobi ``r -> D^{-1} r`` (identity on pins), and its diagonal
        blocks where the coarse matrix reuses them (else ``None``)."""
        raise NotImplementedError

    def coarse(self, A_psd, C, D):
        """``r -> P A_c^-1 P^T r``, the coarse correction of ``_implicit.coarse``."""
        raise NotImplementedError

    # shared
    def restricted(self, hvp):
        """``v -> hvp(v)`` on the free particles, the identity on pins."""
        return lambda v: hvp(v * self.free) * self.free + (1.0 - self.free) * v

    def contact(self, w):
        """``(C (N, 3, 3), C in PCG's layout)``, the PSD contact blocks at ``w``, or ``(None, None)``."""
        p = self.p
        if p.contact is None:
            return None, None
        C = ct.blocks(p.displacement(w), p.x0, p.cloth, p.contact, p.free)
        return C, self.per_particle(C)

    def hvp(self, A, C_cg, inertia=1.0, pairs=None):
        """``v -> (inertia M/h^2 + sum_s A_s + C + sum_pairs B) v`` (unrestricted); ``pairs``:
        the self-contact blocks (``_rank_one.RankOne``), applied in ``(N, 3)``."""
        h = self.p.h

        def apply(v):
            out = self.springs(A, v) + inertia * self.m / h**2 * v
            if pairs is not None:
                out = out + self.to_cg(pairs.matvec(self.from_cg(v)))
            # the contact product written once: fused into the springs' padded sum, XLA:CPU
            # ran the whole product 2.5x slower (64x64 drape, float32, planes: 95 against
            # 38 us; docs/notebook.md, 2026-12-06 (night))
            return out if C_cg is None else out + materialized(self.matvec(C_cg, v))

        return apply

    def preconditioner(self, A_psd, C, C_cg, pairs=None):
        """Block Jacobi, or the two-level cycle of ``_implicit.coarse`` around it (SPD); the
        self-contact ``pairs`` add their diagonal blocks to the per-particle ones."""
        Cd, Cd_cg = C, C_cg
        if pairs is not None:
            D = pairs.diagonal(self.p.cloth.num_particles)
            Cd = D if C is None else C + D
            Cd_cg = self.per_particle(Cd)
        jacobi, D = self.jacobi(A_psd, Cd, Cd_cg)
        if not self.two_level:
            return jacobi
        return two_level(self.coarse(A_psd, Cd, D), jacobi, self.restricted(self.hvp(A_psd, C_cg, pairs=pairs)))


class ParticleOps(HessianOps):
    """PCG on ``(N, 3)`` vectors with ``(S, 3, 3)`` blocks (a ``ParticleLayout``, and every
    dense solve)."""

    def column(self, a):
        return a

    def per_particle(self, C):
        return C

    def to_cg(self, v):
        return v

    def from_cg(self, v):
        return v

    def blocks(self, w, terms, *, project_psd: bool):
        return pr.blocks(w, self.p, project_psd=project_psd, terms=terms)

    def springs(self, A, v):
        return self.p.sum(matvec(A, self.p.layout.diff(self.p.cloth.springs, v)))

    def matvec(self, C, v):
        return matvec(C, v)

    def aggregate_mass(self):
        lay = self.p.layout
        return jax.ops.segment_sum(self.p.cloth.mass * self.free[:, 0], lay.aggregates, lay.num_aggregates)

    def jacobi(self, A_psd, C, C_cg):
        return block_jacobi(self.p, A_psd, C_cg), None

    def coarse(self, A_psd, C, D):
        p, lay = self.p, self.p.layout
        factor = coarse_factor(lay.aggregates, lay.num_aggregates, p.cloth.springs, A_psd, particle_blocks(p, C),
                               p.free[:, 0], self.lam_min)
        return coarse_correction(lay.aggregates, lay.num_aggregates, factor, p.free)


class PlaneOps(HessianOps):
    """PCG on planes (``_layout.planes``): vectors ``(3, rows, cols)``, blocks ``(3, 3, S)``, and
    the grid's square blocks as aggregates (a ``PlanarLayout``)."""

    def column(self, a):
        return pl.particle_planes(self.p.layout.stencil, a[:, 0])[None]

    def per_particle(self, C):
        return pl.particle_planes(self.p.layout.stencil, C)

    def to_cg(self, v):
        return pl.to_planes(self.p.layout.stencil, v)

    def from_cg(self, v):
        return pl.from_planes(v)

    def blocks(self, w, terms, *, project_psd: bool):
        p = self.p
        e0, doh = (p.e0, p.d_over_h) if p.e0 is not None else (None, None)
        return pl.radial_blocks(terms.e, terms.along, terms.across, e0, doh, project_psd=project_psd)

    def springs(self, A, v):
        return pl.operator(self.p.layout.stencil, A, v)

    def matvec(self, C, v):
        return pl.matvec(C, v)

    def aggregate_mass(self):
        lay = self.p.layout
        return pl.block_reduce(lay.stencil, lay.block, self.m[0] * self.free[0])

    def diagonal(self, A_psd, C_cg):
        """The diagonal blocks of ``M/h^2 + sum_s A_s (+ C)``, ``(3, 3, rows, cols)``."""
        eye = jnp.eye(3, dtype=A_psd.dtype)[:, :, None, None]
        D = pl.block_sums(self.p.layout.stencil, A_psd) + eye * (self.m[0] / self.p.h**2)
        return D if C_cg is None else D + C_cg

    def jacobi(self, A_psd, C, C_cg):
        # the diagonal blocks written once: the block inverse (and the coarse matrix) read
        # every entry several times (``_fusion``)
        D = materialized(self.diagonal(A_psd, C_cg))
        eye = jnp.eye(3, dtype=A_psd.dtype)[:, :, None, None]
        Dinv = block_inverse(jnp.where(self.free[0] > 0, D, eye), planar=True)
        return functools.partial(pl.matvec, Dinv), D

    def coarse(self, A_psd, C, D):  # blocks of the grid: no scatter, no gather
        lay = self.p.layout
        factor = cholesky(pl.coarse_matrix(lay.stencil, lay.block, A_psd, D, self.free[0]), self.lam_min)
        return pl.coarse_correction(lay.stencil, lay.block, factor, self.free)


def hessian_ops(p: pr.StepProblem, linear) -> HessianOps:
    """The :class:`HessianOps` for ``linear`` (``Cholesky()`` or ``CG(...)``) on ``p``'s
    layout: planes for CG on a ``PlanarLayout``, else ``(N, 3)`` vectors."""
    cls = PlaneOps if isinstance(linear, CG) and isinstance(p.layout, PlanarLayout) else ParticleOps
    return cls(p, linear.preconditioner if isinstance(linear, CG) else None)
