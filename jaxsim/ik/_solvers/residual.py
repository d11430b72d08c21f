"""LM's problem and parameters: the residual of a pose and its geometric Jacobian.

The parameters are the local rotations of the joints that can move an effector, updated
on the right (``_perturb``); a hinge has one parameter, a ball joint three.  The residual
stacks ``sqrt(w_k) (p_k - t_k)`` per effector and, with orientation targets,
``sqrt(w_k / 2) c_k (R_k u - T_k u)`` over the three frame axes ``u`` (``jaxsim.ik._solvers.lm``).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ..._dataclass import pytree_dataclass, static_field
from ..._geometry import quat as _quat
from .._model.pose import moving_joints
from .._model.skeleton import steps_below
from .._model.stacked import fk_stacked, frame_axes, sq_errors, take


@pytree_dataclass
class LMProblem:
    """One LM solve's targets.

    Attributes:
      targets: ``(E, 3)`` effector targets; weights: ``(E,)``.
      orients: ``(E, 4)`` target orientations (unit quaternions) or ``None``.
      orient_weights: ``(E,)`` scene units per radian, or ``None`` without orientations.
      poles: ``(K, 3)`` pole points or ``None``; pole_limbs: static ``K`` triples
        ``(root, middle, end)`` of joints, the limb each pole bends (:func:`pole_rows`).
    """

    targets: jax.Array
    weights: jax.Array
    orients: jax.Array | None = None
    orient_weights: jax.Array | None = None
    poles: jax.Array | None = None
    pole_limbs: tuple = static_field(default=())


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
    ids = np.asarray(dofs.joints)
    return L.at[ids].set(turned(L[ids], v))


def turned(L, v):
    """Rotations ``L (..., 4)`` turned on the right by rotation vectors ``v (..., 3)``:
    ``L (1, v / 2) / |.|`` (radians to first order)."""
    dq = jnp.concatenate([jnp.ones(v.shape[:-1] + (1,), v.dtype), 0.5 * v], axis=-1)
    dq = dq / jnp.sqrt(jnp.sum(dq * dq, axis=-1, keepdims=True))
    return _quat.stack(_quat.mul(_quat.unstack(L, axis=-1), _quat.unstack(dq, axis=-1)), axis=-1)


def _orient_scale(prob: LMProblem):
    """``(E,)`` the orientation rows' scale ``c_k = sqrt(w_k / 2) * orientation weight``."""
    return jnp.sqrt(0.5 * prob.weights) * prob.orient_weights


def pole_rows(a, m, e, pole):
    """``(3,)`` a pole's residual on the limb ``a -> m -> e`` (its root, middle joint and end,
    ``(3,)`` each): ``m_perp - |m_perp| p_hat``, with ``m_perp`` and ``p_perp`` the parts of
    ``m - a`` and ``pole - a`` across the line from ``a`` to ``e`` and ``p_hat`` the unit
    ``p_perp``.  Zero when the middle joint lies in the half-plane of the line and the pole
    (its size is the chord from the middle joint to that half-plane around the line, m),
    and on a straight limb; zero with zero gradient where the pole is on the line."""
    u = _quat.normalize(_quat.sub(e, a), (jnp.zeros_like(a[0]),) * 3)

    def across(x):
        return _quat.sub(x, _quat.scale(_quat.dot(x, u), u))

    mp, pp = across(_quat.sub(m, a)), across(_quat.sub(pole, a))
    zero = (jnp.zeros_like(a[0]),) * 3
    return _quat.sub(mp, _quat.scale(_quat.safe_norm(mp), _quat.normalize(pp, zero)))


def _pole_residuals(P, prob: LMProblem):
    """``(K, 3)`` the poles' residuals at FK's ``P (J, 3)``."""
    a, m, e = (_quat.unstack(take(P, tuple(t[c] for t in prob.pole_limbs), axis=0), axis=-1) for c in range(3))
    return _quat.stack(pole_rows(a, m, e, _quat.unstack(prob.poles, axis=-1)), axis=-1)


def _residual_at(topo, P, G, prob: LMProblem):
    """``(r, worst squared error)`` at FK's ``P (J, 3)``, ``G (J, 4)``: ``r`` stacks the
    position rows ``(E, 3)``, then the frame-axis rows ``(E, 3, 3)`` (effector, axis,
    component), then the pole rows ``(K, 3)``; a pole's squared residual counts as an error."""
    eff = topo.effectors
    pe = take(P, eff, axis=0)
    parts = [(jnp.sqrt(prob.weights)[:, None] * (pe - prob.targets)).reshape(-1)]
    if prob.orients is not None:
        Ru, Tu = frame_axes(take(G, eff, axis=0)), frame_axes(prob.orients)
        parts.append((_orient_scale(prob)[:, None, None] * (Ru - Tu)).reshape(-1))
    e2 = jnp.max(sq_errors(P, G, eff, prob.targets, prob.orients, prob.orient_weights))
    if prob.poles is not None:
        rp = _pole_residuals(P, prob)
        parts.append(rp.reshape(-1))
        e2 = jnp.maximum(e2, jnp.max(jnp.sum(rp * rp, axis=-1)))
    return jnp.concatenate(parts), e2


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
    if prob.poles is not None:  # the chain rule through the limb's three points' columns
        K, parents = len(prob.pole_limbs), topo.parents
        pts = tuple(j for t in prob.pole_limbs for j in t)  # (3K,) root, middle, end per pole
        moves = np.asarray([[steps_below(parents, x, c) is not None for c in cj] for x in pts], dtype)  # (3K, n)
        Px = take(P, pts, axis=0)  # (3K, 3)
        lever = Px[:, None, :] - take(P, cj, axis=0)[None]  # (3K, n, 3)
        Jx = _quat.stack(_quat.cross(om, _quat.unstack(lever, axis=-1)), axis=1) * moves[:, None, :]  # (3K, 3, n)
        a, m, e = (Px.reshape(K, 3, 3)[:, c] for c in range(3))

        def one(a, m, e, p):
            return _quat.stack(pole_rows(_quat.unstack(a), _quat.unstack(m), _quat.unstack(e), _quat.unstack(p)))

        D = jax.vmap(jax.jacfwd(one, argnums=(0, 1, 2)))(a, m, e, prob.poles)  # 3 x (K, 3, 3)
        Jx = Jx.reshape(K, 3, 3, dofs.n)  # (pole, point, component, n)
        rows.append(sum(jnp.einsum("kij,kjn->kin", D[c], Jx[:, c]) for c in range(3)).reshape(-1, dofs.n))
    return jnp.concatenate(rows, axis=0), r
