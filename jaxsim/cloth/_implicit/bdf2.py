"""BDF2 as a backward-Euler step from a shifted state, with variable-step coefficients.

The two-step backward differentiation formula with step ratio ``w = h / h_prev``
(Hairer, Norsett & Wanner, *Solving ODEs I*, §III.5; Grigorieff 1983) is, for positions
and velocities alike,

    y^{n+1} - a y^n + b y^{n-1} = beta h f(y^{n+1}),
    a = (1 + w)^2 / (1 + 2w),  b = w^2 / (1 + 2w),  beta = (1 + w) / (1 + 2w),

and ``a - b = 1``.  With ``x_b = x^n + b (x^n - x^{n-1})`` and ``v_b = v^n + b (v^n - v^{n-1})``
it reads ``x = x_b + beta h v``, ``M (v - v_b) = beta h F(x, v)``: backward Euler's
equations from ``(x_b, v_b)`` over ``beta h``.  So BDF2's positions minimise backward
Euler's incremental potential (17.19) with those three substituted, and the step is
``_implicit``'s Newton solve, derivative and substeps on that problem; ``w = 0`` (no step
before) is backward Euler itself, which starts a rollout.  Pinned particles have
``x^n = x^{n-1}`` and keep ``x_b = x^n`` exactly.

With colliders the shifted base ``x_b`` may lie inside one, so the contact terms are
those of the physical step (``_implicit.contact.build``'s ``at``): lagged at ``x^n``,
Newton started from ``x^n`` (outside every collider, IPC's feasible start), friction
measured on the motion ``x - x^n``, and every Newton step capped by the time of impact
from the current iterate, as in backward Euler's step.

Variable-step BDF2 is zero-stable for ``w < 1 + sqrt(2)``; a step more than
``MAX_RATIO`` times longer than the one before (a substep climbing back two levels at
once, ``_implicit.substeps``) restarts with a backward-Euler step instead.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..._dataclass import pytree_dataclass
from . import problem as pr

#: The largest step ratio ``h / h_prev`` taken as a BDF2 step (below the zero-stability
#: bound ``1 + sqrt(2)``); a longer step is a backward-Euler step.
MAX_RATIO = 2.0


@pytree_dataclass
class Before:
    """BDF2's memory: the state at the start of the last (sub)step, and its length.

    Attributes:
      x: ``(N, 3)`` positions ``x^{n-1}`` (m).
      v: ``(N, 3)`` velocities ``v^{n-1}`` (m/s).
      h: ``()`` the length of the step from them to ``x^n`` (s); 0: none (the next step
        is backward Euler).
    """

    x: jax.Array
    v: jax.Array
    h: jax.Array

    @staticmethod
    def none(x, v) -> "Before":
        """No step before ``(x, v)``: the next step is backward Euler."""
        return Before(x, v, jnp.zeros((), x.dtype))

    def after(self, x, v, h, taken, p=None, w=None) -> "Before":
        """The memory after a step of length ``h`` from ``(x, v)``, where it was ``taken``
        (``p``, ``w``: the step's problem and solution, which BDF2 does not read; the
        memories' one protocol, ``_implicit.trbdf2``)."""
        keep = lambda new, old: jnp.where(taken, new, old)  # noqa: E731
        return Before(keep(x, self.x), keep(v, self.v), keep(jnp.asarray(h, self.h.dtype), self.h))

    def problem(self, cloth, x, v, h, prev, layout, pins=None) -> pr.StepProblem:
        """The problem of a (sub)step of ``h`` from ``(x, v)`` with this memory (module doc)."""
        xb, vb, hb = base(x, v, self, h)
        return pr.StepProblem.build(cloth, xb, vb, hb, prev, layout, start=(x, h), pins=pins)


def ratio(before: Before, h) -> jax.Array:
    """``()`` the step ratio ``h / before.h``, 0 where there is no step before or the
    ratio exceeds ``MAX_RATIO`` (NaN-free in both branches)."""
    has = before.h > 0
    w = h / jnp.where(has, before.h, 1.0)
    return jnp.where(has & (w <= MAX_RATIO), w, 0.0)


def base(x, v, before: Before, h):
    """``(x_b (N,3), v_b (N,3), beta h ())``: the backward-Euler step that is BDF2's."""
    w = ratio(before, h)
    b = w * w / (1.0 + 2.0 * w)
    beta = (1.0 + w) / (1.0 + 2.0 * w)
    return x + b * (x - before.x), v + b * (v - before.v), beta * h


def step_problem(cloth, x, v, h, prev, layout, before, pins=None) -> pr.StepProblem:
    """The problem of a (sub)step of ``h`` from ``(x, v)``: backward Euler's, or that of a
    memory ``before`` (BDF2's :class:`Before`, or a TR-BDF2 stage's, ``_implicit.trbdf2``:
    contact terms from the step's own start, module doc); ``pins``: ``(N, 3)`` the pinned
    particles' positions at its end, or ``None`` (they stay)."""
    if before is None:
        return pr.StepProblem.build(cloth, x, v, h, prev, layout, pins=pins)
    return before.problem(cloth, x, v, h, prev, layout, pins)
