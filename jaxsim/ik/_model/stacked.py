"""One pose as stacked arrays: FK tree level by tree level, and the limit projection and
the effector errors vectorised over joints.

The sweep kernels lay a pose out per joint (lists of component tuples, unrolled over a
tree's static joints), which suits their joint-by-joint updates but makes a 24-joint
loop body thousands of scalar operations, and XLA's compile time grows with them.  A
solver that moves every joint at once (LM) works on ``(..., J, 4)`` arrays instead: FK
is one gather and two quaternion products per tree level (the humanoid has 9 levels),
unrolled for thousands of poses at once and a rolled loop over the levels otherwise (a
vmapped solver's FK sees one pose), the projection onto the limits a few operations over
all joints.  Same formulas as
``fk.fk_tree``, ``projection.project`` and ``pose.effector_sq_errors`` (tested).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..._dataclass import pytree_dataclass, static_field
from ..._geometry import quat as _quat
from .joints import UNROLL_MIN_BATCH
from .projection import clamp, twist_end


@functools.lru_cache(maxsize=None)
def tree_levels(parents: tuple) -> tuple:
    """Static ``(levels, order)`` of a tree: per depth ``d >= 1``, ``(joints, parent rows)``
    with each parent's row in depth ``d - 1``'s list; ``order`` puts the concatenated
    levels back in joint order."""
    depth = [0] * len(parents)
    for i in range(1, len(parents)):
        depth[i] = depth[parents[i]] + 1
    rows = [[i for i in range(len(parents)) if depth[i] == d] for d in range(max(depth) + 1)]
    levels = []
    for d in range(1, len(rows)):
        pos = {j: r for r, j in enumerate(rows[d - 1])}
        levels.append((tuple(rows[d]), tuple(pos[parents[j]] for j in rows[d])))
    flat = [j for r in rows for j in r]
    return tuple(levels), tuple(int(k) for k in np.argsort(flat))


def take(x, idx, axis=-2):
    """``x`` at the static indices ``idx`` along ``axis``: a slice when they are a run."""
    idx = tuple(idx)
    if idx == tuple(range(idx[0], idx[0] + len(idx))):
        return jnp.moveaxis(jnp.moveaxis(x, axis, 0)[idx[0]:idx[0] + len(idx)], 0, axis)
    return jnp.take(x, np.asarray(idx), axis=axis)


def _q(a):
    return _quat.unstack(a, axis=-1)


def _s(v):
    return _quat.stack(v, axis=-1)


@functools.lru_cache(maxsize=None)
def level_table(parents: tuple) -> tuple:
    """Static ``(joints, parents)``, each ``(D, W)``: per tree depth ``d >= 1`` its joints and
    their parents, padded to the widest level with ``J`` (a scratch row); ``J > 1``."""
    levels, _ = tree_levels(parents)
    J, W = len(parents), max(len(j) for j, _ in levels)
    jt, pt = np.full((len(levels), W), J), np.full((len(levels), W), J)
    for d, (joints, _) in enumerate(levels):
        jt[d, :len(joints)] = joints
        pt[d, :len(joints)] = [parents[j] for j in joints]
    return jt, pt


def fk_stacked(parents, offsets, L, *, unroll=None):
    """FK of stacked rotations: ``L (..., J, 4)``, ``offsets (J, 3)`` (or ``(..., J, 3)``,
    per batch element: a clip's translated joints) -> ``(P (..., J, 3), G (..., J, 4))``.

    ``G_i = G_p L_i``, ``P_i = P_p + R(G_p) offsets[i]`` (``fk``), one tree level at a time:
    unrolled (``unroll``; default: at least ``joints.UNROLL_MIN_BATCH`` poses in ``L``'s visible
    batch, where a vmapped FK sees one), or
    as a rolled loop over the levels (:func:`level_table`), which compiles the humanoid's FK
    5x faster and runs as fast on a few dozen poses, and up to 2x slower on thousands
    (docs/notebook.md, "FK by a loop over tree levels").
    """
    J, batch = len(parents), jnp.broadcast_shapes(L.shape[:-2], offsets.shape[:-2])
    if unroll is None:
        unroll = int(np.prod(batch, dtype=np.int64)) >= UNROLL_MIN_BATCH
    if unroll or J == 1:
        levels, order = tree_levels(tuple(parents))
        G = [L[..., :1, :]]
        P = [jnp.broadcast_to(offsets[..., :1, :], L.shape[:-2] + (1, 3))]
        for joints, prow in levels:
            gp, pp = _q(take(G[-1], prow)), _q(take(P[-1], prow))
            P.append(_s(_quat.add(pp, _quat.rotate(gp, _q(take(offsets, joints))))))
            G.append(_s(_quat.mul(gp, _q(take(L, joints)))))
        perm = np.asarray(order)
        return (jnp.take(jnp.concatenate(P, axis=-2), perm, axis=-2),
                jnp.take(jnp.concatenate(G, axis=-2), perm, axis=-2))
    jt, pt = level_table(tuple(parents))

    def pad(x):  # the scratch row J, which padded level entries write and read
        return jnp.concatenate([x, jnp.zeros(x.shape[:-2] + (1, x.shape[-1]), x.dtype)], axis=-2)

    Lp, off = pad(L), pad(offsets)
    G = jnp.broadcast_to(Lp, batch + Lp.shape[-2:])
    P = jnp.zeros(batch + (J + 1, 3), L.dtype).at[..., 0, :].set(offsets[..., 0, :])

    def level(d, GP):
        G, P = GP
        joints, prow = jnp.asarray(jt)[d], jnp.asarray(pt)[d]
        gp, pp = _q(jnp.take(G, prow, axis=-2)), _q(jnp.take(P, prow, axis=-2))
        Pn = _s(_quat.add(pp, _quat.rotate(gp, _q(jnp.take(off, joints, axis=-2)))))
        Gn = _s(_quat.mul(gp, _q(jnp.take(Lp, joints, axis=-2))))
        return G.at[..., joints, :].set(Gn), P.at[..., joints, :].set(Pn)

    G, P = jax.lax.fori_loop(0, jt.shape[0], level, (G, P))
    return P[..., :J, :], G[..., :J, :]


@pytree_dataclass
class Bounds:
    """Joint limits for :func:`apply_bounds`, with the trigonometry of the range ends
    done once (``K`` limited joints).

    Attributes:
      joints: static ``(K,)`` the joints; kinds: static ``(K,)`` ``"hinge" | "swing" | "fixed"``.
      axis: ``(K, 3)`` unit hinge or twist axes.
      lo, hi: ``(K, 4)`` the twists at the range ends, ``(cos(x / 2), sin(x / 2) axis)``.
      cone: ``(K, 2)`` ``cos`` and ``sin`` of half the cone angle.
    """

    joints: tuple = static_field()
    kinds: tuple = static_field()
    axis: jax.Array = None
    lo: jax.Array = None
    hi: jax.Array = None
    cone: jax.Array = None


def bounds(table, joints=None) -> Bounds | None:
    """The :class:`Bounds` of ``table``'s limited joints among ``joints`` (default all), or
    ``None`` when none is limited."""
    if table is None:
        return None
    joints = tuple(j for j in (range(len(table.kinds)) if joints is None else joints) if table.kinds[j] != "free")
    if not joints:
        return None
    ax = take(table.axis, joints, axis=0)

    def end(x):
        return _s(twist_end(take(x, joints, axis=0), _q(ax)))

    half = 0.5 * take(table.swing, joints, axis=0)
    return Bounds(joints, tuple(table.kinds[j] for j in joints), ax, end(table.lo), end(table.hi),
                  jnp.stack([jnp.cos(half), jnp.sin(half)], axis=-1))


def apply_bounds(b: Bounds | None, L):
    """``L (..., J, 4)`` with the joints of ``b`` moved into their limit sets (``projection.clamp``,
    one joint per element)."""
    if b is None:
        return L
    kinds = np.asarray(b.kinds)

    def mask(kind):
        return bool(kinds[0] == kind) if np.all(kinds == kinds[0]) else kinds == kind

    out = clamp(_q(take(L, b.joints)), _q(b.axis), _q(b.lo), _q(b.hi), (b.cone[..., 0], b.cone[..., 1]),
                mask("hinge"), mask("swing"), mask("fixed"))
    return L.at[..., np.asarray(b.joints), :].set(_s(out))


def project_stacked(table, L):
    """``L (..., J, 4)`` with each joint's rotation moved into its limit set (``table`` ``None``: all free)."""
    return apply_bounds(bounds(table), L)


def batch_leading(rows, B):
    """``(*B, J, C)`` from per-joint component tuples ``rows`` (a list of ``J``, each
    component broadcasting to ``B``): the sweep kernels' layout to this module's."""
    return jnp.stack([_s(tuple(jnp.broadcast_to(c, B) for c in r)) for r in rows], axis=-2)


def joint_rows(a):
    """Per-joint component tuples (a list of ``J``) of ``a (*B, J, C)``: the inverse of
    :func:`batch_leading`."""
    return [_q(a[..., i, :]) for i in range(a.shape[-2])]


def frame_axes(G):
    """``(..., 3, 3)``: the frame ``G (..., 4)``'s world axes ``R(G) u``, one row per unit axis ``u``."""
    g = tuple(c[..., None] for c in _q(G))
    eye = np.eye(3)
    return _s(_quat.rotate(g, tuple(jnp.asarray(eye[:, c], G.dtype) for c in range(3))))


def sq_errors(P, G, effectors, targets, orients=None, orient_weights=None):
    """``(..., E)`` per effector ``max(|p - t|, weight * angle)^2`` (``pose.effector_sq_errors``);
    ``P (..., J, 3)``, ``G (..., J, 4)``, ``targets (..., E, 3)``, ``orients (..., E, 4)``."""
    e2 = jnp.sum((take(P, effectors) - targets) ** 2, axis=-1)
    if orients is None:
        return e2
    return jnp.maximum(e2, (orient_weights * angle_errors(G, effectors, orients)) ** 2)


def angle_errors(G, effectors, orients):
    """``(..., E)`` angle (rad) between each effector's frame and its target orientation."""
    return _quat.angle(_quat.mul(_quat.conj(_q(orients)), _q(take(G, effectors))))
