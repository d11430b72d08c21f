"""TR-BDF2: a trapezoidal stage and a BDF2 stage per step, each a backward-Euler problem.

Bank et al. 1985, "Transient simulation of silicon devices and circuits"; Hosea &
Shampine 1996, "Analysis and implementation of TR-BDF2".  With ``gamma = 2 - sqrt(2)`` the
method is second order and L-stable, and its local error constant is about a fifth of
BDF2's.  A step of ``h`` from ``(x^n, v^n)``:

1. The trapezoidal rule over ``gamma h``:
   ``x^g = x^n + (gamma h / 2)(v^n + v^g)``, ``v^g = v^n + (gamma h / 2)(a^n + a^g)``, which
   are backward Euler's equations from ``x_b = x^n + (gamma h / 2) v^n``,
   ``v_b = v^n + (gamma h / 2) a^n`` over ``gamma h / 2``.
2. BDF2 over ``(1 - gamma) h`` through ``x^n`` and ``x^g`` (``_implicit.bdf2``, step ratio
   ``(1 - gamma) / gamma = 1 / sqrt(2)``).

``a^n`` is the acceleration the last stage solved for, ``(v - v_b) / h_b = g + w / h_b^2``
(its contact, friction and wind forces included, as solved).  Before a rollout's first
step it is ``F(x, v) / m`` at the start (springs, gravity, damping:
``_implicit.extrapolate.acceleration``); a scene with colliders or wind, whose forces at a
state are not known before a step solves them, takes backward Euler over ``gamma h`` as
its first step's first stage.  Each stage is ``_implicit.step.implicit``: its own Newton
solve, implicit derivative and adaptive substeps (a trapezoidal substep reads the
acceleration its predecessor solved for).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from jax import lax

from ..._dataclass import pytree_dataclass
from .._info import StepInfo
from .._model.scene import State
from . import problem as pr
from .bdf2 import Before, base
from .extrapolate import SMOOTH_NEWTON, acceleration
from .step import implicit
from .substeps import advance, between

#: The trapezoidal stage's share of the step: ``2 - sqrt(2)`` (both stages' Newton
#: matrices are then ``M / (gamma h / 2)^2 + K``: the BDF2 stage's ``beta h`` is ``gamma h / 2``).
GAMMA = 2.0 - math.sqrt(2.0)


def end_acceleration(p: pr.StepProblem, w) -> jax.Array:
    """``(N, 3)`` the acceleration ``(v - v_b) / h_b`` that the problem ``p`` solved for at
    its solution ``w`` (m/s^2): ``g + w / h_b^2`` on free particles, the pins' own on
    pinned ones."""
    v = advance(p, w)[1]
    return jnp.where(p.free > 0, p.cloth.gravity + w / p.h**2, (v - p.v0) / p.h)


@pytree_dataclass
class Stage:
    """A TR-BDF2 stage's memory: which stage it is and what that stage reads.

    One type for both stages, so that the step compiles one Newton solve, run twice
    (a ``lax.scan`` over the stages).

    Attributes:
      a: ``(N, 3)`` the acceleration the last (sub)stage solved for (m/s^2).
      known: ``()`` bool, ``a`` is known; where not, the trapezoidal stage is backward Euler.
      closing: ``()`` bool, this is the BDF2 stage (else the trapezoidal one).
      before: BDF2's memory (``_implicit.bdf2.Before``), read by the BDF2 stage.
      smooth: ``()`` bool, the last stage converged within
        ``_implicit.extrapolate.SMOOTH_NEWTON`` Newton iterations (``extrapolate="auto"``
        then aims the first PCG solve of the next at the gradient test).
    """

    a: jax.Array
    known: jax.Array
    closing: jax.Array
    before: Before
    smooth: jax.Array

    def problem(self, cloth, x, v, h, prev, layout, pins=None) -> pr.StepProblem:
        """The (sub)stage over ``h`` from ``(x, v)``: the trapezoidal rule as backward
        Euler's problem from ``(x + (h/2) v, v + (h/2) a)`` over ``h / 2`` (over ``h`` from
        ``(x, v)`` where ``a`` is not known), or BDF2's; contact terms from ``x``."""
        half = jnp.where(self.known, 0.5 * h, 0.0)
        xt, vt, ht = x + half * v, v + half * self.a, h - half
        xb, vb, hb = base(x, v, self.before, h)
        pick = lambda b, t: jnp.where(self.closing, b, t)  # noqa: E731
        return pr.StepProblem.build(cloth, pick(xb, xt), pick(vb, vt), pick(hb, ht), prev, layout, start=(x, h),
                                    pins=pins)

    def after(self, x, v, h, taken, p, w) -> "Stage":
        """The memory after a (sub)stage from ``(x, v)`` over ``h`` whose problem ``p`` was
        solved at ``w``, where ``taken``."""
        return Stage(jnp.where(taken, end_acceleration(p, w), self.a), self.known | taken, self.closing,
                     self.before.after(x, v, h, taken & self.closing), self.smooth)


def first(cloth, x, v, layout=None) -> Stage:
    """The memory before a first step from ``(x, v)`` (``(N, 3)``; module doc)."""
    no, yes = jnp.array(False), jnp.array(True)
    if cloth.colliders or cloth.aero:
        return Stage(jnp.zeros_like(x), no, no, Before.none(x, v), yes)
    return Stage(acceleration(cloth, x, v, layout), yes, no, Before.none(x, v), yes)


def step(cloth, state: State, dt, integ, prev, layout, mem: Stage, pins=None, extrapolate=False, guess=None):
    """``(State, StepInfo, Stage)`` after one TR-BDF2 step of ``dt`` from ``state``.

    ``prev``: the colliders at the step's start when they move (interpolated linearly to
    the stage boundary); ``mem``: the memory before the step; ``pins``: ``(N, 3)`` the
    pinned particles' positions at the step's end, or ``None``; ``extrapolate``: start each
    stage's Newton solve from the constant-acceleration extrapolation (the positions
    whose velocity is ``v + h a``, where its incremental potential is lower); ``guess``:
    ``(N, 3)`` end-of-step positions, the second stage's start.  With
    ``ImplicitEuler.extrapolate`` 2 (``"auto"``: where the stage before converged within
    ``SMOOTH_NEWTON`` iterations) the first PCG solve of a stage aims at the gradient
    test (``_implicit.newton``'s ``tight_first``).  The stages run as a
    ``lax.scan`` of one compiled stage.  The step's diagnostics sum (iterations,
    substeps) or take the worse (relative gradient, condition bound) of the two stages'.
    """
    x0, v0 = state.x, state.v
    dtype = x0.dtype
    ends = jnp.asarray([GAMMA, 1.0], dtype)
    lengths = jnp.asarray([GAMMA, 1.0 - GAMMA], dtype) * dt

    def stage(carry, k):
        s, m = carry
        h = lengths[k]
        ck, pk = cloth, None
        if prev is not None:
            pk = between(prev, cloth.colliders, jnp.where(k == 0, 0.0, GAMMA).astype(dtype))
            ck = dataclasses.replace(cloth, colliders=between(prev, cloth.colliders, ends[k]))
        pins_k = None if pins is None else jnp.where(k == 1, pins, x0 + GAMMA * (pins - x0))  # exact at the end
        def extrapolated(p):  # the positions whose velocity is v + h a
            w = p.h * (s.v + h * m.a - p.v0) - p.h**2 * p.cloth.gravity
            if guess is None:
                return w
            return jnp.where(k == 1, (guess - p.x0) - p.prediction, w if extrapolate else p.start)

        start = extrapolated if extrapolate or guess is not None else None
        tight = False
        if extrapolate and guess is None:
            tight = {2: True, 1: False}.get(integ.extrapolate, m.smooth)  # "auto": the last stage was smooth
        s2, info, m2 = implicit(ck, s, h, integ, pk, start, tight, layout, m, pins_k)
        smooth = info.converged & (info.newton_iters <= SMOOTH_NEWTON)
        # the BDF2 stage next, through x^n and the trapezoidal stage's end
        m2 = Stage(m2.a, m2.known, jnp.array(True), Before(x0, v0, lengths[0]), smooth)
        return (s2, m2), info

    (new, end), infos = lax.scan(stage, (state, mem), jnp.arange(2))
    ok = infos.stable[0] & infos.stable[1]
    keep = lambda a, b: jnp.where(ok, a, b)  # noqa: E731
    i1, i2 = (jax.tree_util.tree_map(lambda a, i=i: a[i], infos) for i in (0, 1))
    info = StepInfo(newton_iters=i1.newton_iters + i2.newton_iters, cg_iters=i1.cg_iters + i2.cg_iters,
                    grad_norm=jnp.maximum(i1.grad_norm, i2.grad_norm), rel_grad=jnp.maximum(i1.rel_grad, i2.rel_grad),
                    step_size=i2.step_size, backtracks=i1.backtracks + i2.backtracks, residual=i2.residual,
                    converged=ok & i1.converged & i2.converged, stable=ok, valid=i1.valid,
                    cond_bound=jnp.maximum(i1.cond_bound, i2.cond_bound),
                    substeps=jnp.where(ok, i1.substeps + i2.substeps, 0), trace=i2.trace,
                    pair_overflow=None if i1.pair_overflow is None else i1.pair_overflow | i2.pair_overflow)
    out = State(keep(new.x, x0), keep(new.v, v0))
    return out, info, Stage(keep(end.a, mem.a), mem.known | ok, jnp.array(False), Before.none(x0, v0),
                            keep(end.smooth, mem.smooth))
