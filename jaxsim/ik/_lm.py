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
XLA:CPU, docs/ik.md) and solves ``(J^T J + mu I) d = -J^T r`` by Cholesky, ``mu = lambda trace(J^T J) / n``.
IK is redundant, so ``J^T J`` is always singular: the damping makes the system
positive definite (``lambda >= LAMBDA_MIN``, so its condition number stays below
``n / LAMBDA_MIN``), and the step is the damped least-change one (Levenberg 1944;
Marquardt 1963; for IK Wampler 1986).  The trial pose is projected onto the joint
limits; it is accepted if it lowers the cost (then ``lambda /= 3``), else rejected
(``lambda *= 4``).  Rejected trials count as iterations.  Like the sweep solvers it is a
fixed-length ``lax.scan`` of masked no-ops after convergence (or the same loop as a
``while_loop`` with ``early_exit``), vmapped over the batch.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_factor, cho_solve

from .._dataclass import pytree_dataclass
from .._geometry import quat as _quat
from ._limits import hinge_angle, project_all
from ._loop import masked_sweeps
from ._fk import fk_tree
from ._pose import OrientTargets, effector_sq_errors, finish, moving_joints, reachable_flags

#: Bounds on the relative damping ``lambda``; the lower one is ``LAMBDA_MIN_EPS`` machine epsilons.
LAMBDA_MIN_EPS = 1e3
LAMBDA_MAX = 1e10
_AXES = jnp.eye(3)


@pytree_dataclass
class LMState:
    """Loop state of one LM solve.

    Attributes:
      rotations: ``(J, 4)`` local rotations of the current (accepted) pose.
      damping: ``()`` relative damping ``lambda``.
      cost: ``()`` squared residual norm of the current pose.
      sq_error: ``()`` squared worst effector error of the current pose.
    """

    rotations: jax.Array
    damping: jax.Array
    cost: jax.Array
    sq_error: jax.Array


def _dofs(topo, table, orient):
    """Static ``(joint, hinge?)`` per moving joint (fixed joints never move)."""
    out = []
    for i in moving_joints(topo, orient):
        kind = "free" if table is None else table.kinds[i]
        if kind != "fixed":
            out.append((i, kind == "hinge"))
    return tuple(out)


def dofs_index(dofs):
    """Per moving joint, ``(offset into the parameter vector, hinge?)``."""
    out, o = [], 0
    for _, hinge in dofs:
        out.append((o, hinge))
        o += 1 if hinge else 3
    return out


def _perturb(L, d, dofs, table):
    """Rotations ``L (J, 4)`` turned on the right by the parameter vector ``d (n,)``."""
    o, rows = 0, []
    for i, hinge in dofs:
        if hinge:
            v, o = d[o] * table.axis[i], o + 1
        else:
            v, o = d[o:o + 3], o + 3
        rows.append(jnp.concatenate([jnp.ones((1,), d.dtype), 0.5 * v]))
    if not rows:
        return L
    ids = jnp.array([i for i, _ in dofs])
    dq = jnp.stack(rows)
    dq = dq / jnp.sqrt(jnp.sum(dq * dq, axis=-1, keepdims=True))
    new = _quat.stack(_quat.mul(_quat.unstack(L[ids], axis=-1), _quat.unstack(dq, axis=-1)), axis=-1)
    return L.at[ids].set(new)


def _pose(topo, offsets, L):
    J = len(topo.parents)
    return fk_tree(topo.parents, offsets, [_quat.unstack(L[i]) for i in range(J)], topo.active)


def _residual(topo, offsets, L, tgt, w, orient):
    """``(r, sq_errors)``: the stacked residual and the per-effector squared errors."""
    return _residual_at(topo, *_pose(topo, offsets, L), tgt, w, orient)


def _frame_rows(topo, G, w, orient):
    """Per effector slot ``k`` and frame axis ``u``: ``(k, u, c_k, R(G_e) u)``, with
    ``c_k = sqrt(w_k / 2) * orientation weight`` (the orientation rows' scale)."""
    out = []
    for k, e in enumerate(topo.effectors):
        c = jnp.sqrt(0.5 * w[k]) * orient.weights[k]
        for u in _AXES:
            u = _quat.unstack(u.astype(w[k].dtype))
            out.append((k, u, c, _quat.rotate(G[e], u)))
    return out


def _residual_at(topo, P, G, tgt, w, orient):
    """``_residual`` at the pose's world positions ``P`` and frames ``G`` (lists of tuples)."""
    parts = [jnp.sqrt(w[k]) * (_quat.stack(P[e]) - _quat.stack(tgt[k])) for k, e in enumerate(topo.effectors)]
    if orient is not None:
        parts += [c * (_quat.stack(Ru) - _quat.stack(_quat.rotate(orient.rotations[k], u)))
                  for k, u, c, Ru in _frame_rows(topo, G, w, orient)]
    r = jnp.concatenate(parts)
    return r, functools.reduce(jnp.maximum, effector_sq_errors(topo, P, G, tgt, orient))


def geometric_jacobian(topo, offsets, L, tgt, w, orient, dofs, table):
    """``(J, r)``: the residual's Jacobian ``(m, n)`` from one FK pass, and the residual ``(m,)``.

    Turning joint ``i`` on the right by ``d`` turns everything below it about the world axis
    ``omega = R(G_i) d`` through the joint's position ``p_i``, so the position rows of effector
    ``e`` are ``omega_u x (p_e - p_i)`` per parameter axis ``u`` and its orientation rows
    ``omega_u x (R_e v)`` per frame axis ``v``; both are zero unless ``i`` is ``e`` or one of
    its ancestors (the geometric Jacobian, Orin and Schrader 1984; Buss 2004 §2).  A hinge has
    one axis, its own.  Equal to ``jax.jacfwd`` of the residual at ``d = 0`` (tested).
    """
    P, G = _pose(topo, offsets, L)
    dtype = offsets.dtype
    zero = jnp.zeros((3,), dtype)
    axes = []  # per parameter: (joint, world axis tuple)
    for i, hinge in dofs:
        locals_ = [_quat.unstack(table.axis[i])] if hinge else [_quat.unstack(u.astype(dtype)) for u in _AXES]
        axes.extend((i, _quat.rotate(G[i], u)) for u in locals_)
    r, _ = _residual_at(topo, P, G, tgt, w, orient)

    def block(k, scale, lever):
        anc = set(topo.path[k])  # the effector and its ancestors
        cols = [scale * _quat.stack(_quat.cross(om, lever(i))) if i in anc else zero for i, om in axes]
        return jnp.stack(cols, axis=1)

    rows = [block(k, jnp.sqrt(w[k]), lambda i, e=e: _quat.sub(P[e], P[i])) for k, e in enumerate(topo.effectors)]
    if orient is not None:
        rows += [block(k, c, lambda i, Ru=Ru: Ru) for k, _, c, Ru in _frame_rows(topo, G, w, orient)]
    return jnp.concatenate(rows, axis=0), r


def lm_one(offsets, targets, local0, weights, tol, table, orients, orient_weights, damping, *, topo, max_iters,
           trace, early_exit):
    """One LM solve: ``targets (E, 3)``, ``local0 (J, 4)``, ``orients (E, 4)`` or ``None``.

    Returns the ``IKResult`` of one target (``rotations (J, 4)``, ``error (E,)``, ...).
    """
    J, E = len(topo.parents), len(topo.effectors)
    dtype = offsets.dtype
    tgt = [_quat.unstack(targets[k]) for k in range(E)]
    w = [weights[k] for k in range(E)]
    orient = None if orients is None else OrientTargets([_quat.unstack(orients[k]) for k in range(E)],
                                                        [orient_weights[k] for k in range(E)])
    dofs = _dofs(topo, table, orient is not None)
    n = sum(1 if h else 3 for _, h in dofs)
    lam_min = LAMBDA_MIN_EPS * jnp.finfo(dtype).eps
    L0 = _quat.stack([_quat.stack(q) for q in project_all(table, [_quat.unstack(local0[i]) for i in range(J)])])
    r0, e0 = _residual(topo, offsets, L0, tgt, w, orient)
    res = functools.partial(_residual, topo, offsets, tgt=tgt, w=w, orient=orient)

    def project(L):
        return _quat.stack([_quat.stack(q) for q in project_all(table, [_quat.unstack(L[i]) for i in range(J)])])

    def jac(L):
        return geometric_jacobian(topo, offsets, L, tgt, w, orient, dofs, table)

    hinge_at = [k for k, _ in enumerate(dofs_index(dofs)) if dofs_index(dofs)[k][1]]

    def solve(Jac, r, damping):
        A = Jac.T @ Jac
        mu = damping * (jnp.trace(A) / n + jnp.finfo(dtype).tiny)
        return cho_solve(cho_factor(A + mu * jnp.eye(n, dtype=dtype)), -(Jac.T @ r))

    def sweep(s: LMState):
        Jac, r = jac(s.rotations)
        d = solve(Jac, r, s.damping)
        if hinge_at:  # a hinge on a bound whose step points out of range is held (one active-set pass)
            held = jnp.zeros((n,), bool)
            for k in hinge_at:
                o, i = dofs_index(dofs)[k][0], dofs[k][0]
                lim = table.joint(i)
                ax, lo, hi = lim.axis, lim.lo, lim.hi
                phi = hinge_angle(_quat.unstack(s.rotations[i]), ax)
                eps = 1e3 * jnp.finfo(dtype).eps
                held = held.at[o].set(((phi <= lo + eps) & (d[o] < 0)) | ((phi >= hi - eps) & (d[o] > 0)))
            d = jnp.where(jnp.any(held), solve(jnp.where(held, 0.0, Jac), r, s.damping), d)
        d = jnp.where(jnp.all(jnp.isfinite(d)), d, 0.0)
        trial = project(_perturb(s.rotations, d, dofs, table))
        rt, et = res(trial)
        ct = jnp.sum(rt * rt)
        ok = ct < s.cost
        new = LMState(rotations=jnp.where(ok, trial, s.rotations),
                      damping=jnp.clip(jnp.where(ok, s.damping / 3, s.damping * 4), lam_min, LAMBDA_MAX),
                      cost=jnp.where(ok, ct, s.cost), sq_error=jnp.where(ok, et, s.sq_error))
        return new, new.sq_error

    s0 = LMState(rotations=L0, damping=jnp.asarray(damping, dtype), cost=jnp.sum(r0 * r0), sq_error=e0)
    if n == 0:
        state, iters, errs = s0, jnp.zeros((), jnp.int32), (jnp.broadcast_to(jnp.sqrt(e0), (max_iters,))
                                                            if trace else None)
    else:
        state, iters, errs = masked_sweeps(sweep, s0, _quat.safe_sqrt(e0), jnp.zeros((), jnp.int32), e0 <= tol * tol,
                                           tol, max_iters=max_iters, trace=trace, early_exit=early_exit)
    local = [_quat.unstack(state.rotations[i]) for i in range(J)]
    return finish(topo, offsets, local, tgt, orient, tol, iters, reachable_flags(topo, offsets, tgt, ()), errs)


@functools.partial(jax.jit, static_argnames=("topo", "max_iters", "trace", "early_exit"))
def run_lm(offsets, targets, local0, weights, tol, table, orients, orient_weights, damping, *, topo, max_iters,
           trace, early_exit=False):
    """LM IK over a flat batch: ``targets (N, E, 3)``, ``local0 (N, J, 4)``, ``orients (N, E, 4)`` or
    ``None``; ``weights``/``orient_weights`` ``(E,)``.  Returns a batch-leading ``IKResult``."""
    one = functools.partial(lm_one, topo=topo, max_iters=max_iters, trace=trace, early_exit=early_exit)
    axes = (None, 0, 0, None, None, None, None if orients is None else 0, None, None)
    return jax.vmap(one, in_axes=axes)(offsets, targets, local0, weights, tol, table, orients, orient_weights,
                                       damping)
