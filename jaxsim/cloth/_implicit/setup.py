"""What every Newton iteration of one implicit step reads, fixed while tracing (``newton``)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..._dataclass import pytree_dataclass
from .._integrators import ImplicitEuler
from .._linear import Cholesky
from . import problem as pr
from .hessian import hessian_ops
from .._self import pairs as sp
from .._self.pairs import PairSet


@pytree_dataclass
class Evaluation:
    """``g`` and what comes with it at one ``w``, from one pass over the springs.

    Attributes:
      g: ``()`` the objective ``g(w)`` (J).
      grad: ``(N, 3)`` ``grad g(w)`` on free particles, 0 on pinned ones (N).
      terms: the spring terms at ``w`` (``problem.SpringTerms``).
      pairs: the self-contact pairs ``g`` counted (``_self.pairs.PairSet``), ``None``
        without self-contact.
      parts: the colliders', self-contact's and wind's terms (``problem.ContactParts``),
        ``None`` for a scene with springs only.
    """

    g: jax.Array
    grad: jax.Array
    terms: pr.SpringTerms
    pairs: PairSet | None = None
    parts: pr.ContactParts | None = None


class NewtonSetup:
    """The step problem, the settings and the pieces derived from them once per trace.

    Args:
      p: the step problem (``stop_gradient`` inputs).
      integ: the ``ImplicitEuler`` settings.

    Attributes:
      linear: ``integ.linear(N)``: ``Cholesky()`` or ``CG(...)``.
      dense: the linear solve is Cholesky.
      ops: the Hessian's pieces in PCG's layout (``hessian.hessian_ops``).
      free: ``(N, 1)`` 1.0 on free particles; ``free3``: ``(3N,)`` the same per coordinate.
      m: ``(N, 1)`` masses (kg).
    """

    def __init__(self, p: pr.StepProblem, integ: ImplicitEuler):
        self.p, self.integ = p, integ
        c = p.cloth
        self.N = c.num_particles
        self.free = p.free
        self.m = c.mass[:, None]
        self.dtype = p.x0.dtype
        self.eps = jnp.finfo(self.dtype).eps
        self.linear = integ.linear(self.N)
        self.dense = isinstance(self.linear, Cholesky)
        self.objective = functools.partial(pr.incremental_potential, p=p)
        self.grad = jax.grad(self.objective)
        self.free3 = self.free.repeat(3, axis=1).reshape(-1)
        self.ops = hessian_ops(p, self.linear)  # PCG on planes on a grid scene (``_layout``)

    def at(self, pairs) -> pr.StepProblem:
        """The step problem with the self-contact pairs ``pairs`` (itself without self-contact)."""
        return self.p.with_pairs(pairs)

    def pairs_at(self, w, last: PairSet | None = None) -> PairSet | None:
        """The self-contact pairs at ``w (N, 3)`` (``None`` without self-contact): drawn from
        ``last``'s candidates where ``w`` is in their region, else from a new search whose
        region the next iterations may stay in (``_self.pairs``)."""
        sc = self.p.selfc
        if sc is None:
            return None
        return sp.draw(sc, last, self.p.positions(w), None, sp.margin(sc))

    def evaluate(self, w, pairs: PairSet | None = None) -> Evaluation:
        """:class:`Evaluation` at ``w (N, 3)``: one pass over the springs.  With self-contact,
        over ``pairs`` (a set found for a motion through ``w``), by default those at ``w``
        (:meth:`pairs_at`)."""
        if self.p.selfc is not None and pairs is None:
            pairs = self.pairs_at(w)
        p = self.at(pairs)
        t, parts = pr.spring_terms(w, p), pr.contact_parts(w, p)
        return Evaluation(pr.objective(w, p, t, parts), pr.gradient(w, p, t, parts) * self.free, t, pairs, parts)
