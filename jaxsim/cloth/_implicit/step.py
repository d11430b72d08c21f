"""One implicit step: backward Euler, BDF2 or a TR-BDF2 stage, on the whole step or in adaptive substeps."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from .._checks import valid_inputs
from .._explicit import bounded
from .._info import StepInfo
from .._integrators import ImplicitEuler
from .._layout import Layout
from .._model.scene import Cloth, State
from . import bdf2
from . import problem as pr
from . import substeps as sb
from .implicit_diff import solution
from .newton import newton


def implicit(cloth: Cloth, state: State, dt, integ: ImplicitEuler, prev=None, start=None, tight=False,
             layout: Layout | None = None, before: bdf2.Before | None = None, pins=None, memory=None):
    """``(State, StepInfo, Before | None)`` after one step of ``dt`` from ``state``.

    ``prev``: the colliders at the start of the step when they move; ``start``: Newton's
    first iterate as a function of the step's problem (``p -> w``), or ``None``;
    ``tight``: its ``tight_first``; ``before``: BDF2's memory (``_implicit.bdf2``) or a TR-BDF2
    stage's (``_implicit.trbdf2``), ``None`` for backward Euler, and the memory for the
    next step is returned (``None`` likewise);
    ``pins``: ``(N, 3)`` the pinned particles' positions at the end of the step (other
    rows unused), or ``None``: they stay; ``memory``: with adaptive substeps, a rollout's
    ``_implicit.substeps.Memory`` (``None``: the whole step first), and ``StepInfo.memory``
    is the next step's.
    """
    if not integ.max_substep_depth:
        return _whole(cloth, state, dt, integ, prev, start, tight, layout, before, pins)
    return _substepped(cloth, state, dt, integ, prev, start, tight, layout, before, pins, memory)


def _whole(cloth: Cloth, state: State, dt, integ: ImplicitEuler, prev, start, tight, layout, before, pins):
    """:func:`implicit` on the whole step."""
    x0, v0, h = state.x, state.v, dt
    valid = valid_inputs(cloth, dt)
    p = bdf2.step_problem(cloth, x0, v0, h, prev, layout, before, pins)
    rtol = integ.resolved_rtol(x0.dtype)
    p_const = jax.tree_util.tree_map(lax.stop_gradient, p)
    if start is not None and not p.touches:  # contact starts from x^n or its push-out
        start = lax.stop_gradient(start(p_const))
    else:
        start = None
    s = newton(p_const, integ, rtol, start, tight_first=tight)
    end = s.iterate
    w = solution(integ, end.w, p)
    x, v = sb.advance(p, w)
    ok = valid & ~s.fail & bounded(cloth, x, v)
    x, v = jnp.where(ok, x, x0), jnp.where(ok, v, v0)
    gnorm = jnp.linalg.norm(end.grad)
    info = StepInfo(newton_iters=s.it, cg_iters=s.cg, grad_norm=jnp.where(jnp.isfinite(gnorm), gnorm, jnp.inf),
                    rel_grad=end.rel, step_size=s.alpha, backtracks=s.bt, residual=s.res,
                    converged=ok & (end.rel <= rtol), stable=ok, valid=valid,
                    cond_bound=pr.condition_bound(p_const, end.terms), substeps=ok.astype(jnp.int32), trace=s.trace,
                    pair_overflow=s.overflow)
    return State(x, v), info, None if before is None else before.after(x0, v0, h, ok, p, w)


def _substepped(cloth: Cloth, state: State, dt, integ: ImplicitEuler, prev, start, tight, layout, before, pins,
                memory=None):
    """:func:`implicit` with adaptive substeps (``_implicit.substeps``): the search's first
    attempt is the whole step, or ``h / 2^memory.level`` in a rollout."""
    x0, v0 = state.x, state.v
    valid = valid_inputs(cloth, dt)
    const = lambda a: jax.tree_util.tree_map(lax.stop_gradient, a)  # noqa: E731
    unread = None if cloth.damped else cloth.damping  # an undamped scene's step never reads it
    scene = jax.tree_util.tree_map(lambda a: a if a is unread else lax.stop_gradient(a), cloth)
    if start is not None:
        start_fn = start
        start = lambda p: lax.stop_gradient(start_fn(p))  # noqa: E731
    found = sb.search(scene, const(x0), const(v0), const(dt), integ, integ.resolved_rtol(x0.dtype),
                      const(prev), layout, start, tight, const(before), const(pins), memory)
    x, v, last = sb.replay(cloth, x0, v0, dt, integ, prev, layout, found, before, pins)
    ok = valid & ~found.failed & bounded(cloth, x, v)
    t = found.totals
    info = StepInfo(newton_iters=t.newton_iters, cg_iters=t.cg_iters, grad_norm=t.grad_norm, rel_grad=t.rel_grad,
                    step_size=t.step_size, backtracks=t.backtracks, residual=t.residual,
                    converged=ok & t.converged, stable=ok, valid=valid, cond_bound=t.cond_bound,
                    substeps=jnp.where(ok, found.count, 0), trace=t.trace, pair_overflow=t.overflow,
                    memory=sb.remember(found, memory, integ))
    if before is not None:
        last = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), last, before)
    return State(jnp.where(ok, x, x0), jnp.where(ok, v, v0)), info, last
