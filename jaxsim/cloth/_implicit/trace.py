"""Per-iteration Newton logs of an implicit step (``ImplicitEuler(trace=True)``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from ..._dataclass import pytree_dataclass

#: ``NewtonTrace.hessian`` codes: which Hessian gave the iteration's direction.
HESSIANS = ("exact", "shifted", "clamped", "stationary")


@pytree_dataclass
class NewtonTrace:
    """One entry per Newton iteration, each array ``(newton_iters,)`` (``(2 newton_iters,)``
    with adaptive substeps, whose deepest level may run that many); entries after the
    last iteration taken are NaN (floats) or -1 (integers).

    Attributes:
      g: objective ``g(w)`` after the iteration (J).
      rel: relative gradient after the iteration (``StepInfo.rel_grad``'s measure).
      step: ``max|alpha dx| / h``, the lab's step test (m/s).  An iteration whose step
        came out non-finite is not taken (``StepInfo.stable`` is then False), nor is the
        last step of a stationary-point phase that did not lower the relative gradient
        (``_implicit.newton.STATIONARY_STEPS``): each logs step 0 and the ``g`` and ``rel`` Newton
        goes on from (where the phase began).  A phase cut off by ``newton_iters`` also
        returns there; the steps it took stay logged.
      alpha: the line search's step size.
      backtracks: the line search's halvings.
      cg: PCG iterations of the iteration, summed over its tries (0 with Cholesky).
      hessian: index into ``HESSIANS``: ``0`` the exact spring blocks (or the clamped
        ones with ``project_psd=True``), ``1`` the exact Hessian with the inertia term
        shifted, ``2`` every block clamped (``project_psd="auto"``'s fallbacks), ``3`` the
        exact Hessian solved for the nearby stationary point (``_implicit.newton.STATIONARY_REL``).
    """

    g: jax.Array
    rel: jax.Array
    step: jax.Array
    alpha: jax.Array
    backtracks: jax.Array
    cg: jax.Array
    hessian: jax.Array

    @staticmethod
    def empty(n: int, dtype) -> NewtonTrace:
        nan, neg = jnp.full((n,), jnp.nan, dtype), jnp.full((n,), -1, jnp.int32)
        return NewtonTrace(g=nan, rel=nan, step=nan, alpha=nan, backtracks=neg, cg=neg, hessian=neg)

    def record(self, k, **entries) -> NewtonTrace:
        """This trace with iteration ``k``'s entries written (every field, by keyword)."""
        return NewtonTrace(**{name: lax.dynamic_update_index_in_dim(getattr(self, name),
                                                                    jnp.asarray(v, getattr(self, name).dtype), k, 0)
                              for name, v in entries.items()})
