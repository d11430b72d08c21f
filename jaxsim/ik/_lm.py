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
(``geometric_jacobian``; equal to ``jax.jacfwd`` of the residual, and far cheaper on
XLA:CPU, docs/ik.md) and solves ``(J^T J + mu I) d = -J^T r`` by Cholesky, ``mu = lambda trace(J^T J) / n``,
or with fewer residuals than parameters the same step as ``d = -J^T y``, ``(J J^T + mu I) y = r``.
IK is redundant, so ``J^T J`` is always singular: the damping makes the system
positive definite (``lambda >= LAMBDA_MIN``, so its condition number stays below
``n / LAMBDA_MIN``), and the step is the damped least-change one (Levenberg 1944;
Marquardt 1963; for IK Wampler 1986).  The trial pose is projected onto the joint
limits; it is accepted if it lowers the cost (then ``lambda /= 3``), else rejected
(``lambda *= 4``).  Rejected trials count as iterations.  Like the sweep solvers it is a
fixed-length ``lax.scan`` of masked no-ops after convergence (or the same loop as a
``while_loop`` with ``early_exit``), vmapped over the batch.

A pose is stacked ``(J, 4)`` arrays (``_stacked``: FK one tree level at a time, the limit
projection and the Jacobian's columns vectorised over joints), not the sweep kernels'
per-joint lists: the loop body is a few hundred operations instead of thousands, which
XLA compiles several times faster (docs/notebook.md, "LM on stacked poses").
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import cho_factor, cho_solve

from .._dataclass import pytree_dataclass
from .._geometry import quat as _quat
from .._geometry.horn import best_rotation
from ._projection import hinge_angle
from ._loop import masked_sweeps
from ._pose import moving_joints, reachable_flags
from ._result import IKResult
from ._stacked import angle_errors, apply_bounds, bounds, fk_stacked, frame_axes, project_stacked, sq_errors, take

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
    """

    rotations: jax.Array
    damping: jax.Array
    cost: jax.Array
    sq_error: jax.Array
    positions: jax.Array
    frames: jax.Array


@pytree_dataclass
class LMProblem:
    """One LM solve's targets.

    Attributes:
      targets: ``(E, 3)`` effector targets; weights: ``(E,)``.
      orients: ``(E, 4)`` target orientations (unit quaternions) or ``None``.
      orient_weights: ``(E,)`` scene units per radian, or ``None`` without orientations.
    """

    targets: jax.Array
    weights: jax.Array
    orients: jax.Array | None = None
    orient_weights: jax.Array | None = None


@dataclasses.dataclass(frozen=True)
class Dofs:
    """LM's parameters (static): a ball joint has three columns, a hinge one.

    Attributes:
      joints: ``(M,)`` the joints with parameters (moving and not fixed), increasing.
      hinge: ``(M,)`` whether each is a hinge.
      cols: ``(M, 3)`` each joint's columns in the parameter vector (a hinge's one thrice).
      col_joint: ``(n,)`` each column's joint; col_axis: ``(n,)`` its local axis (0-2;
        0 for a hinge, whose axis is the table's).
    """

    joints: tuple
    hinge: tuple
    cols: tuple
    col_joint: tuple
    col_axis: tuple

    @property
    def n(self) -> int:
        return len(self.col_joint)

    @property
    def col_hinge(self) -> tuple:
        """``(n,)`` whether each column is a hinge's."""
        return tuple(self.hinge[self.joints.index(j)] for j in self.col_joint)

    @property
    def hinge_cols(self) -> tuple:
        """``(joint, column)`` of every hinge."""
        return tuple((j, c[0]) for j, h, c in zip(self.joints, self.hinge, self.cols) if h)


def _dofs(topo, table, orient: bool) -> Dofs:
    """The parameters of the joints a solve may turn (fixed joints never move)."""
    joints, hinge, cols, cj, ca = [], [], [], [], []
    for i in moving_joints(topo, orient):
        kind = "free" if table is None else table.kinds[i]
        if kind == "fixed":
            continue
        o, h = len(cj), kind == "hinge"
        joints.append(i)
        hinge.append(h)
        cols.append((o, o, o) if h else (o, o + 1, o + 2))
        cj.extend([i] if h else [i, i, i])
        ca.extend([0] if h else [0, 1, 2])
    return Dofs(tuple(joints), tuple(hinge), tuple(cols), tuple(cj), tuple(ca))


def _perturb(L, d, dofs: Dofs, table):
    """Rotations ``L (J, 4)`` turned on the right by the parameter vector ``d (n,)``:
    ``L_i <- L_i (1, v_i / 2) / |.|``, ``v_i = d[cols_i]`` (a hinge: ``d_o`` times its axis)."""
    if not dofs.joints:
        return L
    v = d[np.asarray(dofs.cols)]
    if any(dofs.hinge):
        v = jnp.where(np.asarray(dofs.hinge)[:, None], v * take(table.axis, dofs.joints, axis=0), v)
    dq = jnp.concatenate([jnp.ones(v.shape[:-1] + (1,), d.dtype), 0.5 * v], axis=-1)
    dq = dq / jnp.sqrt(jnp.sum(dq * dq, axis=-1, keepdims=True))
    ids = np.asarray(dofs.joints)
    new = _quat.stack(_quat.mul(_quat.unstack(L[ids], axis=-1), _quat.unstack(dq, axis=-1)), axis=-1)
    return L.at[ids].set(new)


def _aligned_root(topo, offsets, L, P, G, prob: LMProblem, moved):
    """The start ``L (J, 4)`` (with its FK ``P (J, 3)``, ``G (J, 4)``) with its root turned by
    Horn's (1987) rotation that best aligns the effectors (seen from the root) with their
    targets, projected onto the root's limit, where that lowers the cost: ``(L, P, G)``.
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


def _orient_scale(prob: LMProblem):
    """``(E,)`` the orientation rows' scale ``c_k = sqrt(w_k / 2) * orientation weight``."""
    return jnp.sqrt(0.5 * prob.weights) * prob.orient_weights


def _residual_at(topo, P, G, prob: LMProblem):
    """``(r, worst squared error)`` at FK's ``P (J, 3)``, ``G (J, 4)``: ``r`` stacks the
    position rows ``(E, 3)`` then the frame-axis rows ``(E, 3, 3)`` (effector, axis, component)."""
    eff = topo.effectors
    pe = take(P, eff, axis=0)
    parts = [(jnp.sqrt(prob.weights)[:, None] * (pe - prob.targets)).reshape(-1)]
    if prob.orients is not None:
        Ru, Tu = frame_axes(take(G, eff, axis=0)), frame_axes(prob.orients)
        parts.append((_orient_scale(prob)[:, None, None] * (Ru - Tu)).reshape(-1))
    e2 = sq_errors(P, G, eff, prob.targets, prob.orients, prob.orient_weights)
    return jnp.concatenate(parts), jnp.max(e2)


def _residual(topo, offsets, L, prob: LMProblem):
    """``(r, worst squared error)`` of the local rotations ``L (J, 4)``."""
    return _residual_at(topo, *fk_stacked(topo.parents, offsets, L), prob)


def geometric_jacobian(topo, offsets, L, prob: LMProblem, dofs: Dofs, table):
    """``(J, r)``: the residual's Jacobian ``(m, n)`` from one FK pass, and the residual ``(m,)``.

    Turning joint ``i`` on the right by ``d`` turns everything below it about the world axis
    ``omega = R(G_i) d`` through the joint's position ``p_i``, so the position rows of effector
    ``e`` are ``omega_u x (p_e - p_i)`` per parameter axis ``u`` and its orientation rows
    ``omega_u x (R_e v)`` per frame axis ``v``; both are zero unless ``i`` is ``e`` or one of
    its ancestors (the geometric Jacobian, Orin and Schrader 1984; Buss 2004 §2).  A hinge has
    one axis, its own.  All columns at once: ``(E, 3, n)`` and ``(E, 3, 3, n)`` blocks masked by
    the static ancestor table.  Equal to ``jax.jacfwd`` of the residual at ``d = 0`` (tested).
    """
    return jacobian_at(topo, *fk_stacked(topo.parents, offsets, L), prob, dofs, table)


def jacobian_at(topo, P, G, prob: LMProblem, dofs: Dofs, table):
    """:func:`geometric_jacobian` at FK's ``P (J, 3)``, ``G (J, 4)`` (LM carries the FK of its
    accepted pose, so an iteration takes one FK pass: its trial's)."""
    r, _ = _residual_at(topo, P, G, prob)
    cj, dtype = dofs.col_joint, P.dtype
    local = jnp.asarray(np.eye(3)[np.asarray(dofs.col_axis)], dtype)
    if any(dofs.hinge):
        local = jnp.where(np.asarray(dofs.col_hinge)[:, None], take(table.axis, cj, axis=0), local)
    om = _quat.rotate(_quat.unstack(take(G, cj, axis=0), axis=-1), _quat.unstack(local, axis=-1))  # n world axes
    anc = np.asarray([[j in topo.path[k] for j in cj] for k in range(len(topo.effectors))], dtype)  # (E, n)
    lever = take(P, topo.effectors, axis=0)[:, None, :] - take(P, cj, axis=0)[None]  # (E, n, 3)
    Jp = _quat.stack(_quat.cross(om, _quat.unstack(lever, axis=-1)), axis=1)  # (E, 3, n)
    rows = [(Jp * (jnp.sqrt(prob.weights)[:, None, None] * anc[:, None, :])).reshape(-1, dofs.n)]
    if prob.orients is not None:
        Ru = frame_axes(take(G, topo.effectors, axis=0))  # (E, 3, 3): axis v, component
        Jo = _quat.stack(_quat.cross(tuple(c[None, None] for c in om), _quat.unstack(Ru[:, :, None, :], axis=-1)),
                         axis=2)  # (E, 3, 3, n)
        rows.append((Jo * (_orient_scale(prob)[:, None, None, None] * anc[:, None, None, :])).reshape(-1, dofs.n))
    return jnp.concatenate(rows, axis=0), r


#: Systems up to this size are solved by :func:`spd_solve`'s unrolled Cholesky, larger ones by LAPACK.
UNROLLED_CHOLESKY_MAX = 16


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


def _held_hinges(L, d, dofs: Dofs, table, dtype):
    """``(n,)`` bool: a hinge on a bound whose direction ``d`` (the steepest descent
    ``-J^T r``) points out of its range: the active set of a projected Newton method
    (Bertsekas 1982, §2), so one solve, without those columns, gives the step."""
    held = jnp.zeros((dofs.n,), bool)
    hc = dofs.hinge_cols
    if not hc:
        return held
    js, cs = tuple(j for j, _ in hc), np.asarray([c for _, c in hc])
    phi = hinge_angle(_quat.unstack(take(L, js, axis=0), axis=-1), _quat.unstack(take(table.axis, js, axis=0),
                                                                                  axis=-1))
    lo, hi, eps = take(table.lo, js, axis=0), take(table.hi, js, axis=0), 1e3 * jnp.finfo(dtype).eps
    return held.at[cs].set(((phi <= lo + eps) & (d[cs] < 0)) | ((phi >= hi - eps) & (d[cs] > 0)))


def lm_one(offsets, targets, local0, weights, tol, table, orients, orient_weights, damping, *, topo, max_iters,
           trace, early_exit):
    """One LM solve: ``targets (E, 3)``, ``local0 (J, 4)``, ``orients (E, 4)`` or ``None``.

    Returns the ``IKResult`` of one target (``rotations (J, 4)``, ``error (E,)``, ...).
    """
    dtype = offsets.dtype
    prob = LMProblem(targets, weights, orients, None if orients is None else orient_weights)
    dofs = _dofs(topo, table, orients is not None)
    n = dofs.n
    lam_min = LAMBDA_MIN_EPS * jnp.finfo(dtype).eps
    L0 = project_stacked(table, local0)
    moved = bounds(table, dofs.joints)  # only these change in the loop (fixed joints are not among them)
    P0, G0 = fk_stacked(topo.parents, offsets, L0)
    if len(topo.effectors) > 1 and dofs.joints and dofs.joints[0] == 0 and not dofs.hinge[0]:
        L0, P0, G0 = _aligned_root(topo, offsets, L0, P0, G0, prob, moved)
    r0, e0 = _residual_at(topo, P0, G0, prob)

    def solve(Jac, r, damping):
        # (J^T J + mu I)^-1 J^T = J^T (J J^T + mu I)^-1: the smaller of the two systems
        # (m rows against n parameters, static), the same step.
        m = Jac.shape[0]
        A = Jac @ Jac.T if m < n else Jac.T @ Jac
        mu = damping * (jnp.trace(A) / n + jnp.finfo(dtype).tiny)
        A = A + mu * jnp.eye(A.shape[0], dtype=dtype)
        if m < n:
            return -(Jac.T @ spd_solve(A, r))
        return spd_solve(A, -(Jac.T @ r))

    def sweep(s: LMState):
        Jac, r = jacobian_at(topo, s.positions, s.frames, prob, dofs, table)
        if dofs.hinge_cols:  # a hinge on a bound that descent would push out of range is held
            Jac = jnp.where(_held_hinges(s.rotations, -(Jac.T @ r), dofs, table, dtype), 0.0, Jac)
        d = solve(Jac, r, s.damping)
        d = jnp.where(jnp.all(jnp.isfinite(d)), d, 0.0)
        trial = apply_bounds(moved, _perturb(s.rotations, d, dofs, table))
        Pt, Gt = fk_stacked(topo.parents, offsets, trial)
        rt, et = _residual_at(topo, Pt, Gt, prob)
        ct = jnp.sum(rt * rt)
        ok = ct < s.cost
        new = LMState(rotations=jnp.where(ok, trial, s.rotations),
                      damping=jnp.clip(jnp.where(ok, s.damping / 3, s.damping * 4), lam_min, LAMBDA_MAX),
                      cost=jnp.where(ok, ct, s.cost), sq_error=jnp.where(ok, et, s.sq_error),
                      positions=jnp.where(ok, Pt, s.positions), frames=jnp.where(ok, Gt, s.frames))
        return new, new.sq_error

    s0 = LMState(rotations=L0, damping=jnp.asarray(damping, dtype), cost=jnp.sum(r0 * r0), sq_error=e0,
                 positions=P0, frames=G0)
    if n == 0:
        state, iters, errs = s0, jnp.zeros((), jnp.int32), (jnp.broadcast_to(jnp.sqrt(e0), (max_iters,))
                                                            if trace else None)
    else:
        state, iters, errs = masked_sweeps(sweep, s0, _quat.safe_sqrt(e0), jnp.zeros((), jnp.int32), e0 <= tol * tol,
                                           tol, max_iters=max_iters, trace=trace, early_exit=early_exit)
    return _result(topo, offsets, state.rotations, prob, tol, iters, errs)


def _result(topo, offsets, L, prob: LMProblem, tol, iters, errs) -> IKResult:
    """The ``IKResult`` of one solve's final rotations ``L (J, 4)`` (``_pose.finish``'s fields)."""
    P, G = fk_stacked(topo.parents, offsets, L)
    err = jnp.sqrt(jnp.sum((take(P, topo.effectors, axis=0) - prob.targets) ** 2, axis=-1))
    ok = jnp.all(err <= tol)
    ang = None
    if prob.orients is not None:
        ang = angle_errors(G, topo.effectors, prob.orients)
        ok = ok & jnp.all(prob.orient_weights * ang <= tol)
    tgt = [_quat.unstack(t) for t in prob.targets]
    return IKResult(rotations=L, positions=P, error=err, iterations=iters, converged=ok,
                    reachable=reachable_flags(topo, offsets, tgt, ()), trace=errs, angle_error=ang)


@functools.partial(jax.jit, static_argnames=("topo", "max_iters", "trace", "early_exit"))
def run_lm(offsets, targets, local0, weights, tol, table, orients, orient_weights, damping, *, topo, max_iters,
           trace, early_exit=False):
    """LM IK over a flat batch: ``targets (N, E, 3)``, ``local0 (N, J, 4)``, ``orients (N, E, 4)`` or
    ``None``; ``weights``/``orient_weights`` ``(E,)``.  Returns a batch-leading ``IKResult``."""
    one = functools.partial(lm_one, topo=topo, max_iters=max_iters, trace=trace, early_exit=early_exit)
    axes = (None, 0, 0, None, None, None, None if orients is None else 0, None, None)
    return jax.vmap(one, in_axes=axes)(offsets, targets, local0, weights, tol, table, orients, orient_weights,
                                       damping)
