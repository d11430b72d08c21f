"""Newton's method with a backtracking line search on the step problem (lab Algorithm 2).

One iteration is named pieces: the direction (``direction``: the Hessian's parts and the
solve, or a stationary-point solve in a phase), the line search (``line_search``), the
stationary-point phase's bookkeeping (:func:`phase_step`) and the stop test
(:func:`stop_test`), passing named records (``setup.Evaluation``, ``direction.Direction``,
``line_search.Trial``, :class:`Phase`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jax import lax

from ..._dataclass import pytree_dataclass
from .._integrators import ImplicitEuler
from . import direction as dr
from . import problem as pr
from .line_search import line_search
from .newton_state import Iterate, NewtonState
from .setup import NewtonSetup
from .trace import NewtonTrace

#: ``project_psd="auto"``: once the relative gradient is below ``STATIONARY_REL`` and the
#: exact Hessian was found indefinite, Newton solves the exact Hessian for the nearby
#: stationary point of ``g`` (PCG through negative curvature) and takes the full step: a
#: stationary point solves backward Euler's equations whether or not it is a minimum of
#: ``g``.  Near a buckling cloth's saddle the shifted Hessian converges linearly (0.75 per
#: iteration over 27 iterations of one step of scene C 64x64 k = 1e3), the exact one
#: quadratically (docs/cloth.md, stiff cloth).  The first such step can raise the relative gradient
#: before the next ones bring it down (the quadratic model of a nearly singular Hessian
#: holds only close to the stationary point: on a C 32x32 k = 1e5 step 6.6e-9, 2.8e-6,
#: 5.9e-7, 1.2e-7, 4.9e-9, 8.9e-12), so they run as a phase, a watchdog (Chamberlain et al.
#: 1982): up to ``STATIONARY_STEPS`` steps, each staying below ``STATIONARY_REL`` and each
#: after the first cutting the relative gradient by ``STATIONARY_CONTRACT``, until one lowers
#: it below ``STATIONARY_DECREASE`` times its value where the phase began.  A phase that
#: does not returns to where it began (its last iteration is not taken), and the next waits
#: until the relative gradient is ``STATIONARY_RETRY`` times that value.
STATIONARY_REL, STATIONARY_DECREASE, STATIONARY_RETRY = 1e-3, 1.0, 0.1
STATIONARY_STEPS, STATIONARY_CONTRACT = 6, 0.5

#: Newton also stops once the gradient test holds and an iteration cut the relative
#: gradient by less than this factor: the gradient is at the dtype's noise floor, where the
#: lab's step test cannot be met (float32 scene C 32x32 k = 1e5: relative gradients of
#: 1.5e-5 to 2.3e-5 against rtol 1e-4 over the last five iterations of a step, each step
#: 1.2e-6 to 1.5e-6 m/s against tol 1e-6).
FLOOR_RATIO = 0.5


def _where(cond, a, b):
    """``a`` where ``cond`` else ``b``, leaf by leaf (pytrees of one structure)."""
    return jax.tree_util.tree_map(lambda x, y: jnp.where(cond, x, y), a, b)


def cg_tolerance(sv: NewtonSetup, s: NewtonState, rtol):
    """The PCG solve's relative residual target at this iteration: ``cg_tol``, or the
    forcing term ``min(forcing, rel)`` of inexact Newton (Eisenstat & Walker 1996), and
    from a start one iteration away the reduction the gradient test needs."""
    if sv.dense:
        return 0.0
    lin, cur = sv.linear, s.iterate
    tol = cg_tol = lin.tol
    if lin.forcing > 0 and sv.integ.newton_iters > 1:
        tol = jnp.maximum(cg_tol, jnp.minimum(lin.forcing, cur.rel))
        tol = jnp.where(s.tight & (s.it == 0), jnp.maximum(cg_tol, jnp.minimum(tol, rtol / cur.rel)), tol)
    return tol


def search_direction(sv: NewtonSetup, s: NewtonState, tol):
    """``(direction, tried)``: the minimising direction, or with ``project_psd="auto"`` and
    Newton close to a stationary point (or in a phase) the stationary-point solve
    (``tried``: ``()`` bool, the latter was taken)."""
    cur = s.iterate
    parts = dr.hessian_parts(sv, cur.w, cur.terms, cur.pairs)
    if sv.integ.project_psd != "auto":
        return dr.minimising(sv, cur.w, -cur.grad, parts, s.guess, tol), jnp.array(False)
    tried = (s.phase > 0) | (s.indefinite & (cur.rel < s.stationary_below))
    if not sv.dense:  # one PCG solve serves the stationary point and the first minimising try
        return dr.auto_cg(sv, -cur.grad, parts, s.guess, tol, stationary=tried), tried
    # (dense: one conditional.  Falling back to the minimising direction in a nested
    # conditional deadlocked XLA:CPU under vmap.)
    d = lax.cond(tried, lambda: dr.stationary(sv, -cur.grad, parts),
                 lambda: dr.minimising(sv, cur.w, -cur.grad, parts, s.guess, tol))
    return d, tried


@pytree_dataclass
class Phase:
    """A stationary-point phase's outcome at one iteration.

    Attributes:
      old: the :class:`Iterate` to fall back to (the phase's start inside a phase, else
        the current one).
      anchor: the phase's start for the next iteration (``None`` unless ``"auto"``).
      count: ``()`` int32 phase steps taken after this iteration (0: no phase).
      rejected: ``()`` bool, the phase ends here without its last step.
      below: ``()`` the relative gradient below which the next phase may begin.
    """

    old: Iterate
    anchor: Iterate | None
    count: jax.Array
    rejected: jax.Array
    below: jax.Array


def phase_step(s: NewtonState, tried, rel, ok) -> Phase:
    """On until a step beats the relative gradient where the phase began, back there if it
    stops contracting or runs out of steps (module constants ``STATIONARY_*``)."""
    cur, in_phase = s.iterate, s.phase > 0
    if s.anchor is None:
        return Phase(cur, None, jnp.int32(0), jnp.array(False), s.stationary_below)
    old = _where(in_phase, s.anchor, cur)
    beat = rel < STATIONARY_DECREASE * old.rel
    go_on = (tried & ~beat & ok & (s.phase + 1 < STATIONARY_STEPS) & (rel < STATIONARY_REL)
             & (~in_phase | (rel < STATIONARY_CONTRACT * cur.rel)))
    rejected = tried & ~beat & ~go_on
    below = jnp.where(rejected, STATIONARY_RETRY * old.rel, s.stationary_below)
    # the anchor: the phase's start (the current iterate outside a phase)
    return Phase(old, old, jnp.where(go_on, s.phase + 1, 0), rejected, below)


def stop_test(sv: NewtonSetup, cur: Iterate, step, w_new, rel, rtol):
    """``()`` bool, Newton may stop at ``w_new``: the gradient test (and the lab's step test
    with a ``tol``, unless at the gradient's noise floor), or nothing left to resolve."""
    integ = sv.integ
    dmax = jnp.max(jnp.abs(step))
    converged = rel <= rtol
    if integ.tol is not None:  # the lab's step test too, unless at the gradient's noise floor
        floor = rel > FLOOR_RATIO * cur.rel  # no longer improving
        converged = converged & ((dmax / sv.p.h < integ.tol) | floor)
    stalled = dmax <= 4 * sv.eps * jnp.max(jnp.abs(w_new * sv.free))  # nothing left that the dtype can resolve
    return converged | stalled | (rel <= 4 * sv.eps)


def iteration(sv: NewtonSetup, s: NewtonState, rtol) -> NewtonState:
    """One Newton iteration: direction, line search, phase bookkeeping, stop test."""
    cur = s.iterate
    d, tried = search_direction(sv, s, cg_tolerance(sv, s, rtol))
    t = line_search(sv, cur.w, cur.g, cur.grad, d.dx, full=tried, pairs=cur.pairs)
    step = t.alpha * t.dx  # dx is 0 on pins
    w_new = cur.w + step
    rel = pr.relative_gradient(t.at.grad, w_new, sv.at(t.at.pairs), t.at.terms, t.at.parts)
    ok = jnp.all(jnp.isfinite(w_new)) & jnp.isfinite(t.at.g) & jnp.all(jnp.isfinite(t.at.grad))
    overflow = s.overflow
    if overflow is not None:  # pairs were missed on this motion: it is not taken
        ok = ok & ~t.at.pairs.overflow
        overflow = overflow | t.at.pairs.overflow
    ph = phase_step(s, tried, rel, ok)
    taken = ok & ~ph.rejected
    done = stop_test(sv, cur, step, w_new, rel, rtol) & taken & (ph.count == 0) | ~ok
    new = _where(taken, Iterate(w_new, t.at.g, t.at.grad, rel, t.at.terms, t.at.pairs), ph.old)
    trace = s.trace
    if trace is not None:  # a failed step or phase is not taken
        dmax = jnp.max(jnp.abs(step))
        trace = trace.record(s.it, g=new.g, rel=new.rel, step=jnp.where(taken, dmax / sv.p.h, 0.0),
                             alpha=t.alpha, backtracks=t.backtracks, cg=d.cg, hessian=d.hessian)
    in_phase = s.phase > 0
    return NewtonState(iterate=new,
                       guess=jnp.where(taken, step, jnp.where(ph.rejected & ~in_phase, s.guess, 0.0)), it=s.it + 1,
                       cg=s.cg + d.cg, bt=s.bt + t.backtracks, alpha=t.alpha, res=d.res,
                       indefinite=jnp.where(ph.rejected, s.indefinite, d.hessian != 0),
                       stationary_below=ph.below, phase=ph.count, tight=s.tight, done=done, fail=s.fail | ~ok,
                       anchor=ph.anchor, trace=trace, overflow=overflow)


def _start_or_labs(sv: NewtonSetup, wg, w0, last=None):
    """``(w, evaluation, better)``: the start ``wg`` where ``g`` is lower there than at the lab's
    start ``w0`` (``better``; NaN never wins), else ``w0``.  Without moved pins ``g(w0)``
    costs no pass over the springs (``problem.start_objective``), and ``w0`` is evaluated
    only where ``wg`` loses; with them (they stretch their springs at ``w0``) both are.
    The two evaluations are passes of one loop: one evaluation in the compiled program."""
    p = sv.p
    lab_g = pr.start_objective(p) if p.pin_to is None else None

    def body(c):
        k, _, e_g, _ = c
        w = jnp.where(k == 0, wg, w0)
        e = sv.evaluate(w, sv.pairs_at(w, last))
        if lab_g is not None:  # the lab's start is evaluated (pass 1) only where the start lost
            return k + 1, e, e, (k == 0) & (e.g < lab_g)
        e_g = _where(k == 0, e, e_g)  # pass 0: the start's, kept for pass 1's comparison
        better = (k == 1) & (e_g.g < e.g)
        return k + 1, _where(better, e_g, e), e_g, better

    def more(c):
        k, _, _, better = c
        return (k == 0) | ((k == 1) & ~better) if lab_g is not None else k < 2

    blank = jax.tree_util.tree_map(lambda x: jnp.zeros(x.shape, x.dtype), jax.eval_shape(sv.evaluate, w0))
    _, e, _, better = lax.while_loop(more, body, (jnp.int32(0), blank, blank, jnp.array(False)))
    return jnp.where(better, wg, w0), e, better


def initial_state(sv: NewtonSetup, rtol, start=None, tight_first=False, size=None, pairs=None) -> NewtonState:
    """The loop's first carry: the lab's start ``w = -y`` (or the push-out off a moving
    collider), or ``start`` where ``g`` is lower there (NaN never wins; ``g`` at the lab's
    start costs no pass over the springs); its self-contact pairs drawn from ``pairs``'s
    candidates where it is in their region (``NewtonSetup.pairs_at``)."""
    p, integ, free = sv.p, sv.integ, sv.free
    h = p.h
    w0 = p.start
    tight = jnp.array(False)
    if start is None or p.touches:
        cg0 = h * p.v0 * free  # the first direction is about the displacement h v^n
        e0 = sv.evaluate(w0, sv.pairs_at(w0, pairs))
    else:
        w0, e0, better = _start_or_labs(sv, jnp.where(free > 0, start, w0), w0, pairs)
        cg0 = jnp.where(better, 0.0, h * p.v0 * free)
        tight = better & tight_first
    z = jnp.zeros((), sv.dtype)
    over0 = jnp.array(False) if e0.pairs is None else e0.pairs.overflow  # pairs missed at the start
    rel0 = pr.relative_gradient(e0.grad, w0, sv.at(e0.pairs), e0.terms, e0.parts)
    at0 = Iterate(w0, e0.g, e0.grad, rel0, e0.terms, e0.pairs)
    return NewtonState(iterate=at0, guess=cg0,
                       it=jnp.int32(0), cg=jnp.int32(0), bt=jnp.int32(0), alpha=z, res=z,
                       indefinite=jnp.array(False), stationary_below=jnp.asarray(STATIONARY_REL, sv.dtype),
                       phase=jnp.int32(0), tight=tight,
                       done=((rel0 <= rtol) if integ.tol is None else jnp.array(False)) | over0, fail=over0,
                       anchor=at0 if integ.project_psd == "auto" else None,
                       trace=NewtonTrace.empty(size or integ.newton_iters, sv.dtype) if integ.trace else None,
                       overflow=None if e0.pairs is None else e0.pairs.overflow)


def newton(p: pr.StepProblem, integ: ImplicitEuler, rtol, start=None, tight_first=False, limit=None,
           size=None, pairs=None) -> NewtonState:
    """Minimise ``g(., p)`` from ``w = -y`` (the displacement 0, the lab's start), or from
    ``start`` (``(N, 3)``, a deviation ``w``; pinned rows ignored) where ``g`` is lower there.
    ``tight_first``: ``()`` bool, a start one iteration from the solution: the first PCG
    solve from it runs to the relative residual ``rtol / rel`` that the gradient test needs
    (at least ``cg_tol``) where that is below the forcing term.

    Stops when the gradient is small (``rel <= rtol``; at the start already, with
    ``integ.tol=None``, taking no iteration), and with a ``tol`` once the lab's step test
    ``max|alpha dx| / h < tol`` holds too; when the gradient is at rounding level, when
    the step is at the rounding level of ``w`` (no further progress is possible), or
    after ``newton_iters`` iterations (``limit``: ``()`` int32, a traced cap in its place, at
    most ``size``, the trace's length).  ``pairs``: the self-contact pairs Newton ended with
    before (a substep's), whose candidates may serve the start.  Runs on ``stop_gradient``
    inputs: derivatives come from the implicit function theorem instead (``_implicit.implicit_diff``).
    """
    sv = NewtonSetup(p, integ)
    s0 = initial_state(sv, rtol, start, tight_first, size, pairs)
    cap = integ.newton_iters if limit is None else limit
    s = lax.while_loop(lambda s: (s.it < cap) & ~s.done, lambda s: iteration(sv, s, rtol), s0)
    if s.anchor is None:
        return s
    # a phase cut off by the cap: where it began is the better iterate
    return dataclasses.replace(s, iterate=_where(s.phase > 0, s.anchor, s.iterate))
