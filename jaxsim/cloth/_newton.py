"""Newton's method with a backtracking line search on the step problem (lab Algorithm 2)."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
from jax import lax

from . import _contact as ct
from . import _energy as en
from . import _problem as pr
from ._hessian import HessianOps
from ._integrators import ImplicitEuler
from ._linear import Cholesky
from ._linsolve import dense_solve, pcg
from ._newton_state import Iterate, NewtonState
from ._trace import NewtonTrace

#: Armijo constants of the backtracking line search (lab Algorithm 2).
BETA, GAMMA = 0.5, 1e-4

#: ``project_psd="auto"``: when the exact Hessian is not positive definite, the direction is
#: first retried on the exact Hessian plus this many times the inertia term ``M / h^2``
#: (a Levenberg-Marquardt shift in the mass metric, which keeps the springs' curvature),
#: and only if that is still indefinite on the Hessian with every block clamped.  On scene C
#: k = 1e5 (float64) the clamped Hessian alone left Newton creeping for over 30 iterations of
#: one step at a relative gradient of 1e-6-1e-5; see the README's stiff-cloth section.
SHIFT = 1.0

#: ``project_psd="auto"``: once the relative gradient is below ``STATIONARY_REL`` and the
#: exact Hessian was found indefinite, Newton solves the exact Hessian for the nearby
#: stationary point of ``g`` (PCG through negative curvature) and takes the full step: a
#: stationary point solves backward Euler's equations whether or not it is a minimum of
#: ``g``.  Near a buckling cloth's saddle the shifted Hessian converges linearly (0.75 per
#: iteration over 27 iterations of one step of scene C 64x64 k = 1e3), the exact one
#: quadratically (README, stiff cloth).  The first such step can raise the relative gradient
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


def _safe_ratio(num, den):
    r = num / jnp.maximum(den, jnp.finfo(num.dtype).tiny)
    return jnp.where(jnp.isfinite(r), r, jnp.inf)


def newton(p: pr.StepProblem, integ: ImplicitEuler, rtol, start=None, tight_first=False) -> NewtonState:
    """Minimise ``g(., p)`` from ``w = -y`` (the displacement 0, the lab's start), or from
    ``start`` (``(N, 3)``, a deviation ``w``; pinned rows ignored) where ``g`` is lower there.
    ``tight_first``: ``()`` bool, a start one iteration from the solution: the first PCG
    solve from it runs to the relative residual ``rtol / rel`` that the gradient test needs
    (at least ``cg_tol``) where that is below the forcing term.

    Stops when the gradient is small (``rel <= rtol``; at the start already, with
    ``integ.tol=None``, taking no iteration), and with a ``tol`` once the lab's step test
    ``max|alpha dx| / h < tol`` holds too; when the gradient is at rounding level, when
    the step is at the rounding level of ``w`` (no further progress is possible), or
    after ``newton_iters`` iterations.  Runs on ``stop_gradient`` inputs: derivatives come from
    the implicit function theorem instead (``_implicit_diff``).
    """
    c, h = p.cloth, p.h
    N = c.num_particles
    free = p.free
    m = c.mass[:, None]
    dtype = p.x0.dtype
    eps = jnp.finfo(dtype).eps
    lin = integ.linear(N)  # Cholesky() or CG(...)
    dense = isinstance(lin, Cholesky)
    objective = functools.partial(pr.incremental_potential, p=p)
    grad = jax.grad(objective)

    def evaluate(w):
        """``(g(w), grad g(w) on free particles, spring terms at w)``: one pass over the springs."""
        t = pr.spring_terms(w, p)
        return pr.objective(w, p, t), pr.gradient(w, p, t) * free, t

    projection = integ.project_psd  # True, False or "auto"
    f3 = free.repeat(3, axis=1).reshape(-1)
    # PCG on planes on a grid scene (``_planes``)
    ops = HessianOps(p, planar=not dense and c.stencil is not None,
                    preconditioner=None if dense else lin.preconditioner)

    def dense_direction(b, H, indefinite=False):
        """Cholesky (LU with ``indefinite=True``) on ``H (3N, 3N)`` with pinned rows and
        columns replaced by the identity; ``(dx, 0, res, indefinite)``: Cholesky of an
        indefinite ``H`` gives non-finite values."""
        H = H * f3[:, None] * f3[None, :] + jnp.diag(1.0 - f3)
        dx = jnp.linalg.solve(H, b.reshape(-1)) if indefinite else dense_solve(H, b.reshape(-1))
        res = _safe_ratio(jnp.linalg.norm(H @ dx - b.reshape(-1)), jnp.linalg.norm(b))
        return dx.reshape(N, 3), jnp.int32(0), res, ~jnp.all(jnp.isfinite(dx))

    def assembled(A, C, inertia=1.0):
        H = en.assemble(c, A) + jnp.diag(inertia * jnp.repeat(c.mass, 3) / h**2)
        if C is not None:
            eye = jnp.eye(N, dtype=C.dtype)
            H = H + (eye[:, None, :, None] * C[:, :, None, :]).reshape(3 * N, 3 * N)
        return H

    def cg_direction(b, hvp, guess, Minv, tol, indefinite=False):
        """PCG on ``ops.restricted(hvp)`` in its layout; ``b``, ``guess`` and the result ``(N, 3)``."""
        dx, k, res, broke = pcg(ops.restricted(hvp), ops.to_cg(b), ops.to_cg(guess * free), Minv, tol=tol,
                                max_iters=lin.max_iters, indefinite=indefinite)
        return ops.from_cg(dx), k, jnp.where(jnp.isfinite(res), res, jnp.inf), broke

    def hessian_parts(w, terms):
        """``(A_exact, A_psd, C, Minv)`` at ``w``: the exact and the projected spring blocks,
        the PSD contact blocks or ``None`` (``(S, 3, 3)`` and ``(N, 3, 3)``, or planes for
        PCG: ``_hessian``), and the SPD preconditioner (``None`` for Cholesky); shared by
        every direction of an iteration."""
        A_exact = ops.blocks(w, terms, project_psd=False)
        A_psd = ops.blocks(w, terms, project_psd=True)
        C, C_cg = ops.contact(w)
        if dense:
            return A_exact, A_psd, C, None
        return A_exact, A_psd, C_cg, ops.preconditioner(A_psd, C, C_cg)

    def stationary_direction(b, parts, guess, tol):
        """``(dx, cg iterations, residual)``: the exact Hessian solved through negative curvature."""
        A_exact, _, C, Minv = parts
        if dense:
            return dense_direction(b, assembled(A_exact, C), indefinite=True)[:3]
        return cg_direction(b, ops.hvp(A_exact, C), guess, Minv, tol, indefinite=True)[:3]

    def newton_direction(w, b, parts, guess, tol):
        """``(dx, cg iterations, residual, index into _trace.HESSIANS)``."""
        if dense and projection is False:
            return first_definite(lambda: dense_direction(b, jax.hessian(objective)(w).reshape(3 * N, 3 * N)))
        A_exact, A_psd, C, Minv = parts
        if dense:
            if projection is True:
                return first_definite(lambda: dense_direction(b, assembled(A_psd, C)))
            return first_definite(lambda: dense_direction(b, assembled(A_exact, C)),
                                  lambda: dense_direction(b, assembled(A_exact, C, 1.0 + SHIFT)),
                                  lambda: dense_direction(b, assembled(A_psd, C)))
        if projection is True:
            return first_definite(lambda: cg_direction(b, ops.hvp(A_psd, C), guess, Minv, tol))
        if projection is False:  # the exact Hessian, through the autodiff Hessian-vector product
            hvp = lambda v: ops.to_cg(jax.jvp(grad, (w,), (ops.from_cg(v),))[1])  # noqa: E731
            return first_definite(lambda: cg_direction(b, hvp, guess, Minv, tol))
        return first_definite(lambda: cg_direction(b, ops.hvp(A_exact, C), guess, Minv, tol),
                              lambda: cg_direction(b, ops.hvp(A_exact, C, 1.0 + SHIFT), guess, Minv, tol),
                              lambda: cg_direction(b, ops.hvp(A_psd, C), guess, Minv, tol))

    def first_definite(*tries):
        """The first direction of ``tries`` (thunks returning ``(dx, k, res, indefinite)``)
        whose Hessian was not found indefinite, the last one regardless, with the index of
        that try; solver iterations summed over the tries run.  ``project_psd="auto"`` has
        three tries (exact, shifted, clamped), the other settings one."""
        dx, k, res, indefinite = tries[0]()
        if len(tries) == 1:
            return dx, k, res, jnp.int32(0)

        def rest():
            dx2, k2, res2, i2 = first_definite(*tries[1:])
            return dx2, k + k2, res2, i2 + 1

        return lax.cond(indefinite, rest, lambda: (dx, k, res, jnp.int32(0)))

    def first_step(w, dx):
        """1, or the largest step that crosses no collider's surface (IPC's CCD line search)."""
        return jnp.ones((), dtype) if p.contact is None else ct.step_bound(p.displacement(w), dx, p.x0, c, free)

    def line_search(w, gw, gvec, dx, full=False):
        """``(dx, alpha, halvings, g, grad g, spring terms)`` at ``w + alpha dx``.

        The first trial is evaluated with its gradient and spring terms (one pass over
        the springs), which are the Newton loop's next ones whenever the full step is
        accepted; after a halving they are computed once at the accepted point.
        ``full``: ``()`` bool, take the first trial as it is (a stationary-point step)."""
        dx = dx * free
        if not integ.line_search:
            a = first_step(w, dx)
            return (dx, a, jnp.int32(0)) + evaluate(w + a * dx)
        # keep every step a descent step
        slope = jnp.sum(gvec * dx)
        descent = (slope < 0) | full
        dx = jnp.where(descent, dx, -gvec * h**2 / m)
        slope = jnp.where(descent, slope, jnp.sum(gvec * dx))
        slack = 8 * eps * jnp.abs(gw)  # g changes by less than its last bits at convergence
        a0 = first_step(w, dx)

        def cond(s):
            a, k, gnew = s
            armijo = gnew <= gw + GAMMA * a * slope + slack
            return (k < integ.max_backtracks) & ~(armijo & jnp.isfinite(gnew)) & ~full

        def body(s):
            a, k, _ = s
            a = BETA * a
            return a, k + 1, objective(w + a * dx)

        g0, grad0, t0 = evaluate(w + a0 * dx)
        a, k, gnew = lax.while_loop(cond, body, (a0, jnp.int32(0), g0))
        _, gvec_new, t_new = lax.cond(k == 0, lambda: (g0, grad0, t0), lambda: evaluate(w + a * dx))
        return dx, a, k, gnew, gvec_new, t_new

    def body(s: NewtonState) -> NewtonState:
        cur = s.iterate
        tol = cg_tol = 0.0 if dense else lin.tol
        if not dense and lin.forcing > 0 and integ.newton_iters > 1:  # inexact Newton (Eisenstat & Walker 1996)
            tol = jnp.maximum(cg_tol, jnp.minimum(lin.forcing, cur.rel))
            # from a start one iteration away: the residual reduction the gradient test needs
            tol = jnp.where(s.tight & (s.it == 0), jnp.maximum(cg_tol, jnp.minimum(tol, rtol / cur.rel)), tol)
        parts = hessian_parts(cur.w, cur.terms)
        tried = jnp.array(False)
        in_phase = s.phase > 0
        if projection == "auto":  # solve for the stationary point once Newton is close to one
            # (one conditional.  Falling back to the minimising direction in a nested
            # conditional deadlocked XLA:CPU under vmap.)
            tried = in_phase | (s.indefinite & (cur.rel < s.stationary_below))
            stationary = lambda: stationary_direction(-cur.grad, parts, s.guess, tol) + (jnp.int32(3),)  # noqa: E731
            dx, k_cg, res, which = lax.cond(tried, stationary,
                                            lambda: newton_direction(cur.w, -cur.grad, parts, s.guess, tol))
        else:
            dx, k_cg, res, which = newton_direction(cur.w, -cur.grad, parts, s.guess, tol)
        dx, a, k_ls, g_new, gvec, terms = line_search(cur.w, cur.g, cur.grad, dx, full=tried)
        step = a * dx  # dx is 0 on pins
        w_new = cur.w + step
        rel = pr.relative_gradient(gvec, w_new, p, terms)
        ok = jnp.all(jnp.isfinite(w_new)) & jnp.isfinite(g_new) & jnp.all(jnp.isfinite(gvec))
        # a stationary-point phase: on until a step beats the relative gradient where it
        # began, back there if it stops contracting or runs out of steps
        old, anchor, phase = cur, s.anchor, jnp.int32(0)
        rejected = jnp.array(False)
        if anchor is not None:
            old = _where(in_phase, anchor, old)
            beat = rel < STATIONARY_DECREASE * old.rel
            go_on = (tried & ~beat & ok & (s.phase + 1 < STATIONARY_STEPS) & (rel < STATIONARY_REL)
                     & (~in_phase | (rel < STATIONARY_CONTRACT * cur.rel)))
            rejected = tried & ~beat & ~go_on
            anchor = old  # the phase's start (the current iterate outside a phase)
            phase = jnp.where(go_on, s.phase + 1, 0)
        below = jnp.where(rejected, STATIONARY_RETRY * old.rel, s.stationary_below)
        taken = ok & ~rejected
        dmax = jnp.max(jnp.abs(step))
        converged = rel <= rtol
        if integ.tol is not None:  # the lab's step test too, unless at the gradient's noise floor
            floor = rel > FLOOR_RATIO * cur.rel  # no longer improving
            converged = converged & ((dmax / h < integ.tol) | floor)
        stalled = dmax <= 4 * eps * jnp.max(jnp.abs(w_new * free))  # nothing left that the dtype can resolve
        done = (converged | stalled | (rel <= 4 * eps)) & taken & (phase == 0) | ~ok
        new = _where(taken, Iterate(w_new, g_new, gvec, rel, terms), old)
        trace = s.trace
        if trace is not None:  # a failed step or phase is not taken
            trace = trace.record(s.it, g=new.g, rel=new.rel, step=jnp.where(taken, dmax / h, 0.0),
                                 alpha=a, backtracks=k_ls, cg=k_cg, hessian=which)
        return NewtonState(iterate=new,
                           guess=jnp.where(taken, step, jnp.where(rejected & ~in_phase, s.guess, 0.0)), it=s.it + 1,
                           cg=s.cg + k_cg, bt=s.bt + k_ls, alpha=a, res=res,
                           indefinite=jnp.where(rejected, s.indefinite, which != 0), stationary_below=below,
                           phase=phase, tight=s.tight, done=done, fail=s.fail | ~ok, anchor=anchor, trace=trace)

    w0 = p.start
    tight = jnp.array(False)
    if start is None or p.contact is not None:
        cg0 = h * p.v0 * free  # the first direction is about the displacement h v^n
        f0, g0, t0 = evaluate(w0)
    else:  # the lower start of the two (NaN never wins); g at the lab's start costs no pass
        wg = jnp.where(free > 0, start, w0)
        fg, gg, tg = evaluate(wg)
        better = fg < pr.start_objective(p)
        w0, f0, g0, t0 = lax.cond(better, lambda: (wg, fg, gg, tg), lambda: (w0,) + evaluate(w0))
        cg0 = jnp.where(better, 0.0, h * p.v0 * free)
        tight = better & tight_first
    z = jnp.zeros((), dtype)
    rel0 = pr.relative_gradient(g0, w0, p, t0)
    at0 = Iterate(w0, f0, g0, rel0, t0)
    s0 = NewtonState(iterate=at0, guess=cg0,
                     it=jnp.int32(0), cg=jnp.int32(0), bt=jnp.int32(0), alpha=z, res=z,
                     indefinite=jnp.array(False), stationary_below=jnp.asarray(STATIONARY_REL, dtype),
                     phase=jnp.int32(0), tight=tight,
                     done=(rel0 <= rtol) if integ.tol is None else jnp.array(False), fail=jnp.array(False),
                     anchor=at0 if projection == "auto" else None,
                     trace=NewtonTrace.empty(integ.newton_iters, dtype) if integ.trace else None)
    s = lax.while_loop(lambda s: (s.it < integ.newton_iters) & ~s.done, body, s0)
    if s.anchor is None:
        return s
    # a phase cut off by the cap: where it began is the better iterate
    return dataclasses.replace(s, iterate=_where(s.phase > 0, s.anchor, s.iterate))
