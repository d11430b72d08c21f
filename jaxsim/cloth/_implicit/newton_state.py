"""The Newton loop's carry: the iterate and the loop's bookkeeping (``newton``)."""

from __future__ import annotations

import jax

from ..._dataclass import pytree_dataclass
from . import problem as pr
from .trace import NewtonTrace
from .._self.pairs import PairSet


@pytree_dataclass
class Iterate:
    """A Newton iterate with what was evaluated there.

    Attributes:
      w: ``(N, 3)`` deviation ``x - x^n - y`` from the prediction ``y = h v^n + h^2 g``
        (m; ``_implicit.problem`` module doc); ``-y`` on pinned particles (they do not move).
      g: ``()`` objective ``g(w)`` (J).
      grad: ``(N, 3)`` ``grad g(w)`` on free particles, 0 on pinned ones (N).
      rel: ``()`` relative gradient ``|grad|_inf / scale`` at ``w``.
      terms: the spring terms at ``w`` (``_implicit.problem.SpringTerms``), which gave ``g``,
        ``grad`` and ``rel`` and give the next iteration's Hessian blocks.
      pairs: the self-contact pairs counted at ``w`` (``_self.pairs.PairSet``), or ``None``.
    """

    w: jax.Array
    g: jax.Array
    grad: jax.Array
    rel: jax.Array
    terms: pr.SpringTerms
    pairs: PairSet | None = None


@pytree_dataclass
class NewtonState:
    """The Newton loop's carry.

    Attributes:
      iterate: the current :class:`Iterate`.
      guess: ``(N, 3)`` warm start for the next CG solve (the last step).
      it: ``()`` int32 iterations taken.
      cg: ``()`` int32 CG iterations summed.
      bt: ``()`` int32 line-search halvings summed.
      alpha: ``()`` last line-search step size.
      res: ``()`` relative residual of the last linear solve.
      indefinite: ``()`` bool, the last direction did not come from the exact Hessian's
        minimising solve (it was found indefinite).
      stationary_below: ``()`` the relative gradient below which a stationary-point phase
        begins (``STATIONARY_REL``, lowered after a failed phase).
      phase: ``()`` int32 stationary-point steps taken in the current phase (0: none).
      anchor: the :class:`Iterate` where the current stationary-point phase began (a
        failed phase returns to it; ``project_psd="auto"`` only, else ``None``).
      tight: ``()`` bool, the first PCG solve aims at the gradient test (``newton``'s
        ``tight_first`` where its start was taken).
      done: ``()`` bool, the loop has stopped.
      fail: ``()`` bool, a step produced non-finite values (and was not taken).
      trace: the per-iteration log with ``ImplicitEuler(trace=True)``, else ``None``.
      overflow: ``()`` bool, a self-contact pair set had more pairs than slots (that
        iteration was not taken); ``None`` without self-contact.
    """

    iterate: Iterate
    guess: jax.Array
    it: jax.Array
    cg: jax.Array
    bt: jax.Array
    alpha: jax.Array
    res: jax.Array
    indefinite: jax.Array
    stationary_below: jax.Array
    phase: jax.Array
    tight: jax.Array
    done: jax.Array
    fail: jax.Array
    anchor: Iterate | None = None
    trace: NewtonTrace | None = None
    overflow: jax.Array | None = None
