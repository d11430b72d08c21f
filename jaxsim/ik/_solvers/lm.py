"""Damped least squares (Levenberg–Marquardt) IK on joint trees, with limits and orientations.

The parameters are the local rotations of the joints that can move an effector, updated
multiplicatively on the right, ``L_i <- L_i (1, d_i / 2) / |.|`` (``d_i`` a rotation
vector in the joint's frame, radians to first order); a hinge joint has one parameter,
its angle about the hinge axis, so a step never leaves the hinge.  The residual stacks,
per effector ``k``, ``sqrt(w_k) (p_k - t_k)`` and, with orientation targets,
``sqrt(w_k / 2) c_k (R_k u - T_k u)`` over the three axes ``u``: the cost is
``sum_k w_k (|p_k - t_k|^2 + c_k^2 4 sin^2(angle_k / 2))``, the objective the tree CCD
minimises joint by joint.

Each iteration takes the geometric Jacobian ``J`` of the residual from one FK pass
(``residual.geometric_jacobian``; equal to ``jax.jacfwd`` of the residual, and far cheaper on
XLA:CPU, docs/ik.md) and solves ``(J^T J + mu I) d = -J^T r`` by Cholesky, ``mu = lambda trace(J^T J) / n``,
or with fewer residuals than parameters the same step as ``d = -J^T y``, ``(J J^T + mu I) y = r``.
IK is redundant, so ``J^T J`` is always singular: the damping makes the system
positive definite (``lambda >= LAMBDA_MIN``, so its condition number stays below
``n / LAMBDA_MIN``), and the step is the damped least-change one (Levenberg 1944;
Marquardt 1963; for IK Wampler 1986).  The bounds the pose lies on that steepest descent
would push it out of are held first (``active_set``: a held hinge loses its column, a held
ball joint keeps the motions along its bound), the trial pose is projected onto the joint
limits, and it is accepted if it lowers the cost (then ``lambda /= 3``), else rejected
(``lambda *= 4``).  Rejected trials count as iterations.  Like the sweep solvers it is a
fixed-length ``lax.scan`` of masked no-ops after convergence (or the same loop as a
``while_loop`` with ``early_exit``), vmapped over the batch; a large batch with
``early_exit`` runs as a work queue instead (``loop.refill_sweeps``), whose lanes take a
new set as soon as theirs is done.

A pose is stacked ``(J, 4)`` arrays (``stacked``: FK one tree level at a time, the limit
projection and the Jacobian's columns vectorised over joints), not the sweep kernels'
per-joint lists: the loop body is a few hundred operations instead of thousands, which
XLA compiles several times faster (docs/notebook.md, "LM on stacked poses").
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_factor, cho_solve

from ..._dataclass import pytree_dataclass
from ..._geometry import quat as _quat
from ..._geometry.horn import best_rotation
from .active_set import hold_bounds
from .limb_start import limb_start
from .loop import masked_sweeps, refill_sweeps
from .._model.pose import reachable_flags
from .._model.result import IKResult
from .starts import SWIVELS, best_of
from .residual import LMProblem, _dofs, _perturb, _pole_residuals, _residual_at, jacobian_at
from .._model.stacked import angle_errors, apply_bounds, bounds, fk_stacked, project_stacked, take

#: Bounds on the relative damping ``lambda``; the lower one is ``LAMBDA_MIN_EPS`` machine epsilons.
LAMBDA_MIN_EPS = 1e3
LAMBDA_MAX = 1e10


@pytree_dataclass
class LMState:
    """Loop state of one LM solve.

    Attributes:
      rotations: ``(J, 4)`` local rotations of the current (accepted) pose.
      damping: ``()`` relative damping ``lambda``.
      cost: ``()`` squared residual norm of the current pose.
      sq_error: ``()`` squared worst effector error of the current pose.
      positions, frames: ``(J, 3)`` and ``(J, 4)``, the current pose's FK.
      stationary: ``()`` bool, the last sweep found the pose it started from stationary
        (:func:`is_stationary`) after ``STUCK`` trial steps in a row that did not lower the
        cost: LM stops there, short of ``tol`` (a stationary pose whose steps still gain
        goes on).
      rejected: ``()`` int32, trial steps rejected in a row.
    """

    rotations: jax.Array
    damping: jax.Array
    cost: jax.Array
    sq_error: jax.Array
    positions: jax.Array
    frames: jax.Array
    stationary: jax.Array
    rejected: jax.Array


def _aligned_root(topo, offsets, L, P, G, prob: LMProblem, moved):
    """The start ``L (J, 4)`` (with its FK ``P (J, 3)``, ``G (J, 4)``) with its root turned by
    Horn's (1987) rotation that best aligns the effectors (seen from the root) with their
    targets, projected onto the root's limit (``moved``: the root's ``Bounds`` or ``None``), where
    that lowers the cost: ``(L, P, G)``.
    A whole-body turn is the motion LM finds worst from a far start (the limited humanoid's
    unconverged sets were off at every effector).  Not for one effector: Horn's rotation is
    then the shortest arc, which would turn a straight chain back onto its target's line,
    where ``J^T r = 0``."""
    E = len(topo.effectors)
    a = _quat.unstack(take(P, topo.effectors, axis=0) - P[0], axis=-1)
    b = _quat.unstack(prob.targets - P[0], axis=-1)
    R = best_rotation([tuple(c[k] for c in a) for k in range(E)], [tuple(c[k] for c in b) for k in range(E)],
                      [prob.weights[k] for k in range(E)])
    turned = apply_bounds(moved, L.at[0].set(_quat.stack(_quat.mul(R, _quat.unstack(L[0], axis=-1)), axis=-1)))
    Pt, Gt = fk_stacked(topo.parents, offsets, turned)
    ok = jnp.sum(_residual_at(topo, Pt, Gt, prob)[0] ** 2) < jnp.sum(_residual_at(topo, P, G, prob)[0] ** 2)
    return jnp.where(ok, turned, L), jnp.where(ok, Pt, P), jnp.where(ok, Gt, G)


#: A pose is stationary where its projected gradient ``|J^T r|`` (the bounds it is held on
#: removed) is at most ``STATIONARY sqrt(eps)`` times ``|J| |r|`` (Frobenius and Euclidean
#: norms: a cosine, scale-free).  LM's accept test compares costs, which rounding blurs at
#: about ``sqrt(eps)`` relative gradient: the planar arm held on its bound ends at 1.2e-9 in
#: float64 (sqrt(eps) = 1.5e-8) and stays there for hundreds of iterations.
STATIONARY = 4.0
#: ... and LM stops there once this many trial steps in a row have not lowered the cost (its
#: damping grown 4x each): one rejection is routine on the way to a minimum, three at a
#: stationary pose mean rounding has the last word.
STUCK = 3


def is_stationary(Jac, r):
    """``()`` bool: ``|J^T r| <= STATIONARY sqrt(eps) |J| |r|`` (``Jac (m, n)`` with the held
    bounds' motions removed, ``r (m,)``): no descent direction is left inside the limits, to
    rounding, the first-order condition of the constrained least-squares minimum."""
    dtype = Jac.dtype
    rtol2 = STATIONARY * STATIONARY * float(jnp.finfo(dtype).eps)
    g2 = jnp.sum((Jac.T @ r) ** 2)
    return g2 <= rtol2 * jnp.sum(Jac * Jac) * jnp.sum(r * r) + jnp.finfo(dtype).tiny


#: Systems up to this size are solved by :func:`spd_solve`'s unrolled Cholesky, larger ones by LAPACK.
#: The humanoid's 12 x 12 system by LAPACK compiles 10-20% faster, at the same sets/s with
#: limits in the work queue (``ik_ab_humanoid_limits_lm_cholesky.json``), about 10% fewer on
#: the free humanoid and 7% fewer vmapped without the queue (docs/notebook.md, "LM's active
#: set on ball joints").
UNROLLED_CHOLESKY_MAX = 8


def spd_solve(A, b):
    """``A^-1 b`` for a symmetric positive definite ``A (k, k)``, ``b (k,)``, by Cholesky.

    Up to ``UNROLLED_CHOLESKY_MAX`` the factorisation and the two triangular solves are
    unrolled into scalar operations: vmapped, every one is an elementwise operation over
    the batch, which XLA:CPU fuses and vectorises, where a batch of LAPACK calls pays a
    call per element (docs/notebook.md, "LM on stacked poses").
    """
    k = A.shape[0]
    if k > UNROLLED_CHOLESKY_MAX:
        return cho_solve(cho_factor(A), b)
    Lc = [[None] * k for _ in range(k)]
    inv = [None] * k
    for j in range(k):
        d = jnp.sqrt(A[j, j] - sum(Lc[j][p] * Lc[j][p] for p in range(j)))
        inv[j] = 1.0 / d
        for i in range(j + 1, k):
            Lc[i][j] = (A[i, j] - sum(Lc[i][p] * Lc[j][p] for p in range(j))) * inv[j]
        Lc[j][j] = d
    y = [None] * k
    for i in range(k):
        y[i] = (b[i] - sum(Lc[i][p] * y[p] for p in range(i))) * inv[i]
    x = [None] * k
    for i in reversed(range(k)):
        x[i] = (y[i] - sum(Lc[p][i] * x[p] for p in range(i + 1, k))) * inv[i]
    return jnp.stack(x)


@pytree_dataclass
class LMItem:
    """One target set in :func:`_loop.refill_sweeps`'s queue: its loop state and its problem."""

    state: LMState
    prob: LMProblem


def _lm_start(offsets, targets, local0, weights, table, orients, orient_weights, damping, limbs=False, swivel=None,
              *, topo, poles=None, pole_limbs=()):
    """The start of one set (``local0 (J, 4)``): its state and problem.  The root is turned toward
    the targets (``_aligned_root``); with ``limbs`` (a bool, or a traced one) the limbs are bent and
    swung toward them too, turned by ``swivel`` (rad) about their target lines, or toward their
    poles (``poles (K, 3)`` of the limbs ``pole_limbs``; ``limb_start``), where that lowers the cost."""
    dtype = offsets.dtype
    prob = LMProblem(targets, weights, orients, None if orients is None else orient_weights, poles,
                     pole_limbs if poles is not None else ())
    dofs = _dofs(topo, table, orients is not None)
    L0 = project_stacked(table, local0)
    P0, G0 = fk_stacked(topo.parents, offsets, L0)
    if len(topo.effectors) > 1 and dofs.joints and dofs.joints[0] == 0 and not dofs.hinge[0]:
        L0, P0, G0 = _aligned_root(topo, offsets, L0, P0, G0, prob, bounds(table, (0,)))
    r0, e0 = _residual_at(topo, P0, G0, prob)
    L1 = limb_start(topo, table, L0, P0, G0, targets, swivel, prob) if limbs is not False else L0
    if L1 is not L0:
        P1, G1 = fk_stacked(topo.parents, offsets, L1)
        r1, e1 = _residual_at(topo, P1, G1, prob)
        ok = (jnp.sum(r1 * r1) < jnp.sum(r0 * r0)) & limbs
        L0, P0, G0, r0, e0 = (jnp.where(ok, a, b) for a, b in ((L1, L0), (P1, P0), (G1, G0), (r1, r0), (e1, e0)))
    return LMItem(LMState(rotations=L0, damping=jnp.asarray(damping, dtype), cost=jnp.sum(r0 * r0), sq_error=e0,
                          positions=P0, frames=G0, stationary=jnp.zeros((), bool),
                          rejected=jnp.zeros((), jnp.int32)), prob)


def _lm_sweep(s: LMState, prob: LMProblem, offsets, table, *, topo):
    """One LM iteration: ``(new state, its squared worst error, the start pose was stationary)``."""
    dtype = offsets.dtype
    dofs = _dofs(topo, table, prob.orients is not None)
    n = dofs.n
    Jac, r = jacobian_at(topo, s.positions, s.frames, prob, dofs, table)
    if table is not None:  # the bounds that descent would push the pose out of are held
        Jac = hold_bounds(Jac, s.rotations, -(Jac.T @ r), dofs, table)
    flat = is_stationary(Jac, r)
    # (J^T J + mu I)^-1 J^T = J^T (J J^T + mu I)^-1: the smaller of the two systems
    # (m rows against n parameters, static), the same step.
    m = Jac.shape[0]
    A = Jac @ Jac.T if m < n else Jac.T @ Jac
    mu = s.damping * (jnp.trace(A) / n + jnp.finfo(dtype).tiny)
    A = A + mu * jnp.eye(A.shape[0], dtype=dtype)
    d = -(Jac.T @ spd_solve(A, r)) if m < n else spd_solve(A, -(Jac.T @ r))
    d = jnp.where(jnp.all(jnp.isfinite(d)), d, 0.0)
    trial = apply_bounds(bounds(table, dofs.joints), _perturb(s.rotations, d, dofs, table))
    Pt, Gt = fk_stacked(topo.parents, offsets, trial)
    rt, et = _residual_at(topo, Pt, Gt, prob)
    ct = jnp.sum(rt * rt)
    ok = ct < s.cost
    rejected = jnp.where(ok, 0, s.rejected + 1)
    stuck = flat & (rejected >= STUCK)  # stationary, and steps no longer lower the cost: a minimum to rounding
    lam_min = LAMBDA_MIN_EPS * jnp.finfo(dtype).eps
    new = LMState(rotations=jnp.where(ok, trial, s.rotations),
                  damping=jnp.clip(jnp.where(ok, s.damping / 3, s.damping * 4), lam_min, LAMBDA_MAX),
                  cost=jnp.where(ok, ct, s.cost), sq_error=jnp.where(ok, et, s.sq_error),
                  positions=jnp.where(ok, Pt, s.positions), frames=jnp.where(ok, Gt, s.frames), stationary=stuck,
                  rejected=rejected)
    return new, new.sq_error, stuck


def lm_one(offsets, targets, local0, weights, tol, table, orients, orient_weights, damping, limbs=False, swivel=None, *,
           topo, max_iters, trace, early_exit, poles=None, pole_limbs=()):
    """One LM solve: ``targets (E, 3)``, ``local0 (J, 4)``, ``orients (E, 4)`` or ``None``; ``limbs``,
    ``swivel``, ``poles (K, 3)``, ``pole_limbs``: as :func:`_lm_start`.

    Returns the ``IKResult`` of one target (``rotations (J, 4)``, ``error (E,)``, ...).
    """
    start = _lm_start(offsets, targets, local0, weights, table, orients, orient_weights, damping, limbs, swivel,
                      topo=topo, poles=poles, pole_limbs=pole_limbs)
    s0, prob, e0 = start.state, start.prob, start.state.sq_error
    if _dofs(topo, table, orients is not None).n == 0:
        state, iters, errs = s0, jnp.zeros((), jnp.int32), (jnp.broadcast_to(jnp.sqrt(e0), (max_iters,))
                                                            if trace else None)
    else:
        state, iters, errs = masked_sweeps(lambda s: _lm_sweep(s, prob, offsets, table, topo=topo), s0,
                                           _quat.safe_sqrt(e0), jnp.zeros((), jnp.int32), e0 <= tol * tol, tol,
                                           max_iters=max_iters, trace=trace, early_exit=early_exit)
    return _result(topo, offsets, state, prob, tol, iters, errs)


def _result(topo, offsets, s: LMState, prob: LMProblem, tol, iters, errs) -> IKResult:
    """The ``IKResult`` of one solve's final state (``pose.finish``'s fields; its FK is the state's)."""
    L, P, G = s.rotations, s.positions, s.frames
    err = jnp.sqrt(jnp.sum((take(P, topo.effectors, axis=0) - prob.targets) ** 2, axis=-1))
    ok = jnp.all(err <= tol)
    ang = None
    if prob.orients is not None:
        ang = angle_errors(G, topo.effectors, prob.orients)
        ok = ok & jnp.all(prob.orient_weights * ang <= tol)
    if prob.poles is not None:  # every pole met too (its residual within tol, m)
        ok = ok & jnp.all(jnp.sum(_pole_residuals(P, prob) ** 2, axis=-1) <= tol * tol)
    tgt = [_quat.unstack(t) for t in prob.targets]
    return IKResult(rotations=L, positions=P, error=err, iterations=iters, converged=ok,
                    reachable=reachable_flags(topo, offsets, tgt, ()), trace=errs, angle_error=ang,
                    stationary=ok | s.stationary)


#: Batches of at least this many sets solved with ``early_exit`` (and no trace) run as a work
#: queue (``loop.refill_sweeps``) on ``queue_lanes(N)`` lanes.
QUEUE_MIN = 128
#: In the queue with ``seeds > 1``: a start whose worst error has not fallen 4x in 10
#: iterations ends (the limited humanoid's failures are stuck, not slow), and the set's
#: next start begins: 1,000 sets, ``seeds=8``, 97.0% converged both ways, 71.4 -> 30.6 mean
#: iterations (docs/notebook.md).
STALL = (10, 0.25)


def queue_lanes(n: int) -> int:
    """Lanes of the work queue for ``n`` sets: a thirty-second of the batch, at least 32.
    Fewer lanes waste fewer sweeps at the end (the last sets finish alone), more amortise
    the loop's per-sweep cost; on the limited humanoid (float32, 2 cores) 32 lanes for
    1,000 sets and 312 for 10,000 were the fastest tried (docs/notebook.md)."""
    return min(n, max(32, n // 32))


@functools.partial(jax.jit, static_argnames=("topo", "max_iters", "trace", "early_exit", "limbs", "pole_limbs"))
def run_lm(offsets, targets, local0, weights, tol, table, orients, orient_weights, damping, extra=None, *, topo,
           max_iters, trace, early_exit=False, limbs=False, poles=None, pole_limbs=()):
    """LM IK over a flat batch: ``targets (N, E, 3)``, ``local0 (N, J, 4)``, ``orients (N, E, 4)`` or
    ``None``; ``weights``/``orient_weights`` ``(E,)``; ``extra (K - 1, J, 4)``, the further starts
    of ``LevenbergMarquardt(seeds=K)``, or ``None``; ``poles (N, K, 3)`` or ``None``, the pole
    points of the limbs ``pole_limbs`` (static ``(root, middle, end)`` triples).  Returns a
    batch-leading ``IKResult``.

    ``limbs`` (static): the given start gets the limb start (``limb_start``; for the default
    start, not for a caller's); the further starts always do, start ``k`` with
    ``starts.SWIVELS[k]``.

    With ``early_exit``, no trace and ``N >= QUEUE_MIN``, the sets go through a work queue
    (``loop.refill_sweeps``): the same iterations per set, and about ``mean / max`` of
    the vmapped loop's sweeps; a set's further starts run only where its earlier ones failed
    or stalled (``STALL``).
    Otherwise every set runs every start, vmapped, and keeps one (``starts.best_of``).
    """
    N = targets.shape[0]
    K = 1 if extra is None else 1 + extra.shape[0]
    swivels = jnp.asarray(SWIVELS, offsets.dtype)
    if not (early_exit and not trace and N >= QUEUE_MIN and _dofs(topo, table, orients is not None).n):
        part = functools.partial(lm_one, topo=topo, max_iters=max_iters, trace=trace, early_exit=early_exit,
                                 pole_limbs=pole_limbs)

        def one(off, t, L0, w, tl, tb, o, ow, dm, pl, *more):
            return part(off, t, L0, w, tl, tb, o, ow, dm, *more, poles=pl)

        axes = (None, 0, 0, None, None, None, None if orients is None else 0, None, None, None if poles is None else 0)
        if K == 1:
            return jax.vmap(lambda *a: one(*a, limbs), in_axes=axes)(offsets, targets, local0, weights, tol, table,
                                                                     orients, orient_weights, damping, poles)
        starts = jnp.concatenate([local0[:, None], jnp.broadcast_to(extra, (N,) + extra.shape)], axis=1)
        k = jnp.tile(jnp.arange(K), N)

        def flat(a):
            return None if a is None else jnp.repeat(a, K, axis=0)

        res = jax.vmap(one, in_axes=axes + (0, 0))(offsets, flat(targets), starts.reshape((N * K,) + local0.shape[1:]),
                                                   weights, tol, table, flat(orients), orient_weights, damping,
                                                   flat(poles), (k > 0) | limbs, swivels[k % len(SWIVELS)])
        return best_of(res, N, K)
    def start(off, t, L0, w, tb, o, ow, dm, pl):
        return _lm_start(off, t, L0, w, tb, o, ow, dm, limbs, topo=topo, poles=pl, pole_limbs=pole_limbs)

    axes = (None, 0, 0, None, None, None if orients is None else 0, None, None, None if poles is None else 0)
    items0 = jax.vmap(start, in_axes=axes)(offsets, targets, local0, weights, table, orients, orient_weights, damping,
                                           poles)

    def sweep(it: LMItem):
        new, e2, flat = _lm_sweep(it.state, it.prob, offsets, table, topo=topo)
        return LMItem(new, it.prob), e2, flat

    def restart(items: LMItem, k):
        def one(p: LMProblem, L0, sw):
            return _lm_start(offsets, p.targets, L0, p.weights, table, p.orients, p.orient_weights, damping, True, sw,
                             topo=topo, poles=p.poles, pole_limbs=p.pole_limbs)

        return jax.vmap(one)(items.prob, extra[k - 1], swivels[k % len(SWIVELS)])

    out, iters = refill_sweeps(jax.vmap(sweep), items0, items0.state.sq_error, tol, max_iters=max_iters,
                               lanes=queue_lanes(N), seeds=K, restart=restart, stall=STALL)
    return jax.vmap(lambda s, p, k: _result(topo, offsets, s, p, tol, k, None))(out.state, out.prob, iters)
