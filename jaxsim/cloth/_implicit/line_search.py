"""Newton's backtracking line search (lab Algorithm 2, Armijo), bounded by IPC's CCD step."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from ..._dataclass import pytree_dataclass
from . import contact as ct
from .._self import pairs as sp
from .._self import terms as sc
from .setup import Evaluation, NewtonSetup

#: Armijo constants of the backtracking line search (lab Algorithm 2).
BETA, GAMMA = 0.5, 1e-4
#: Halvings of a step whose motion has more self-contact pairs than slots.
SHORTER = 10


@pytree_dataclass
class Trial:
    """The point the line search accepted.

    Attributes:
      dx: ``(N, 3)`` the direction searched: the one given (0 on pins), or the scaled
        negative gradient where that was not a descent direction (m).
      alpha: ``()`` the step taken along ``dx``.
      backtracks: ``()`` int32 halvings.
      at: the :class:`~.setup.Evaluation` at ``w + alpha dx``.
    """

    dx: jax.Array
    alpha: jax.Array
    backtracks: jax.Array
    at: Evaluation


def first_step(sv: NewtonSetup, w, dx, last=None):
    """``(alpha, pairs)``: 1, or the largest step that crosses no collider's surface and no
    self-contact pair (IPC's CCD line search; additive CCD for the pairs), and the
    self-contact pairs on the motion to it (``None`` without self-contact), drawn from
    ``last``'s candidates (the pairs at ``w``) where the motion stays in their region."""
    p = sv.p
    a = jnp.ones((), sv.dtype)
    if p.contact is not None:
        a = ct.step_bound(p.displacement(w), dx, p.x0, p.cloth, sv.free)
    if p.selfc is None:
        return a, None
    x = p.positions(w)
    grow = sp.margin(p.selfc)
    # a long step's boxes can hold more pairs than there are slots: search again without
    # the margin, then halve the step until they fit (at most SHORTER times; a set that
    # still overflows says so and the step is not taken)
    def shorter(c):
        a, _, k = c
        a = jnp.where(k > 1, 0.5 * a, a)
        return a, sp.draw(p.selfc, last, x, a * dx, jnp.where(k == 0, grow, 0.0)), k + 1

    a, seg, _ = lax.while_loop(lambda c: c[1].overflow & (c[2] <= SHORTER + 1), shorter,
                               (a, sp.empty_pairs(p.selfc.capacity, p.selfc.faces, p.selfc.edges, x), jnp.int32(0)))
    return sc.step_bound(p.selfc, seg, x, dx, a), seg


def line_search(sv: NewtonSetup, w, gw, gvec, dx, full=False, pairs=None) -> Trial:
    """Backtrack from ``w`` (objective ``gw``, gradient ``gvec``, self-contact ``pairs``) along ``dx``.

    Every trial is evaluated with its gradient and spring terms (one pass over the
    springs), which are the Newton loop's next ones at the accepted trial.  The first
    trial is evaluated before the loop (most searches end there), the halved ones in it:
    two evaluations in the compiled program, where evaluating only ``g`` at the halved
    trials needed a third to finish (docs/notebook.md, "one copy of each solve").
    ``full``: ``()`` bool, take the first trial as it is (a stationary-point step)."""
    integ, h = sv.integ, sv.p.h
    dx = dx * sv.free
    if not integ.line_search:
        a, seg = first_step(sv, w, dx, pairs)
        return Trial(dx, a, jnp.int32(0), sv.evaluate(w + a * dx, seg))
    # keep every step a descent step
    slope = jnp.sum(gvec * dx)
    descent = (slope < 0) | full
    dx = jnp.where(descent, dx, -gvec * h**2 / sv.m)
    slope = jnp.where(descent, slope, jnp.sum(gvec * dx))
    slack = 8 * sv.eps * jnp.abs(gw)  # g changes by less than its last bits at convergence

    def accepted(a, k, at):
        # the rounding slack only where the decrease the slope predicts is within it: a
        # trial predicted to gain more must really lower g (float32 friction otherwise
        # takes overshoots that rise by less than the slack, and Newton bounces)
        resolved = -a * slope > slack
        armijo = at.g <= gw + GAMMA * a * slope + jnp.where(resolved, 0, slack)
        return (armijo & jnp.isfinite(at.g)) | full | (k >= integ.max_backtracks)

    a0, seg = first_step(sv, w, dx, pairs)

    def body(s):
        a, k, _ = s
        a, k = BETA * a, k + 1
        return a, k, sv.evaluate(w + a * dx, seg)

    a, k, at = lax.while_loop(lambda s: ~accepted(*s), body, (a0, jnp.int32(0), sv.evaluate(w + a0 * dx, seg)))
    return Trial(dx, a, k, at)
