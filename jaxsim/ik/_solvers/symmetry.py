"""Symmetric poses: a chain lying on the line through its root and its target.

Neither CCD nor FABRIK can leave that line by itself (every update is a rotation about a
zero axis, or a move along the line), so such poses are bent first (FABRIK paper, §5.4).
"""

from __future__ import annotations

import dataclasses
import functools

import jax.numpy as jnp
import numpy as np

from ..._geometry import quat as _quat

#: Bend applied to a chain lying on the line of its target (FABRIK paper, section 5.4).
SYMMETRY_BREAK_ANGLE = 0.1


def _bend(axis):
    """The turn by ``SYMMETRY_BREAK_ANGLE`` about the unit vector tuple ``axis``."""
    half = 0.5 * SYMMETRY_BREAK_ANGLE
    return (jnp.full_like(axis[0], np.cos(half)), *_quat.scale(float(np.sin(half)), axis))


def _chain_bend(root, end, target, off_line, reach, done, g_parent, local_m):
    """``(need, r, joint m's bent local rotation)``; ``off_line(ray)``: the pose's largest distance to the line."""
    to_target = _quat.sub(target, root)
    ray = _quat.normalize(to_target, _quat.normalize(_quat.sub(end, root), _quat.perpendicular(to_target)))
    r = _bend(_quat.perpendicular(ray))
    need = (off_line(ray) <= 1e-6 * reach) & ~done
    return need, r, _quat.mul(_quat.conj(g_parent), _quat.mul(r, _quat.mul(g_parent, local_m)))


def break_symmetry_stacked(local, positions, frames, target, reach, done, batch_shape):
    """:func:`break_symmetry_chain` on the rolled loop's stacked ``(J, C, *B)`` arrays
    (``target`` a vector tuple); returns the new local rotations, the caller redoes FK.
    Its own form: through lists it took the rolled CCD solve from 116 to 124 fusions."""
    J, m = local.shape[0], (1 if local.shape[0] > 2 else 0)
    rel = _quat.unstack(positions - positions[:1], axis=1)  # tuple of (J, *B)
    g_parent = _quat.unstack(frames[m - 1]) if m > 0 else _quat.identity(batch_shape, local.dtype)
    need, _, lm = _chain_bend(_quat.unstack(positions[0]), _quat.unstack(positions[J - 1]), target,
                              lambda ray: jnp.max(_quat.safe_norm(_quat.cross(rel, tuple(c[None] for c in ray))), 0),
                              reach, done, g_parent, _quat.unstack(local[m]))
    return jnp.where(need, local.at[m].set(_quat.stack(lm)), local)


def break_symmetry_chain(local, positions, frames, target, reach, done):
    """Bend a chain (per-joint lists) that lies on the line through its root and target:
    joint 1 (a one-bone chain's root) turns by ``SYMMETRY_BREAK_ANGLE`` about a
    perpendicular of the line, other poses are returned unchanged.  Without a second FK:
    turning joint ``m``'s global frame by ``r`` turns every frame below it and swings
    every joint below it about joint ``m``: ``G_k <- r G_k`` (``k >= m``),
    ``P_k <- P_m + r (P_k - P_m)`` (``k > m``), applied where the pose needs it.  Entries
    may have no batch axis (a start pose shared by the batch); the bent ones gain it.
    """
    J, root, m = len(local), positions[0], (1 if len(local) > 2 else 0)
    g_parent = frames[m - 1] if m > 0 else _quat.identity((), local[0][0].dtype)
    need, r, lm = _chain_bend(root, positions[J - 1], target, lambda ray: functools.reduce(
        jnp.maximum, [_quat.safe_norm(_quat.cross(_quat.sub(p, root), ray)) for p in positions]), reach, done,
        g_parent, local[m])
    local, positions, frames = list(local), list(positions), list(frames)
    local[m] = _quat.where(need, lm, local[m])
    pm = positions[m]
    for k in range(m + 1, J):
        positions[k] = _quat.where(need, _quat.add(pm, _quat.rotate(r, _quat.sub(positions[k], pm))), positions[k])
    for k in range(m, J):
        frames[k] = _quat.where(need, _quat.mul(r, frames[k]), frames[k])
    return local, positions, frames


def branch_segments(topo):
    """Per effector slot, the joints of its branch: from the nearest sub-base (a joint with
    several active children), effector or root above it, down to the effector."""
    out = []
    for k, path in enumerate(topo.path):
        start = 0
        for idx, j in enumerate(path[:-1]):
            if len(topo.active_children[j]) > 1 or topo.effector_slot[j] >= 0:
                start = idx
        out.append(path[start:])
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class BendPlan:
    """Static index arrays of :func:`bend_straight` over its ``C`` candidate bends (NumPy).

    Attributes:
      bones: ``(2, nb)`` each branch bone's upper and lower joint.
      pairs: ``(2, np)`` consecutive bones (indices into ``bones``) that must be parallel.
      slot, joint, bone: ``(C,)`` per candidate its effector slot, the joint ``seg[i]`` the
        target line starts from, and that joint's bone below.
      needs: ``(C, max(np, 1))`` the pairs each candidate needs parallel.
      earlier: ``(C, C)`` the candidates before each in its own branch.
      moved: ``(M,)`` the joints some candidate turns; compose: ``(M, K)`` their candidates in
        order, padded with ``C`` (no turn); parent: ``(M,)`` their parents (0 for the root).
    """

    bones: np.ndarray
    pairs: np.ndarray
    slot: np.ndarray
    joint: np.ndarray
    bone: np.ndarray
    needs: np.ndarray
    earlier: np.ndarray
    moved: np.ndarray
    compose: np.ndarray
    parent: np.ndarray


@functools.lru_cache(maxsize=None)
def _bend_plan(topo) -> BendPlan | None:
    """The :class:`BendPlan` of ``topo`` (``None`` when no branch has a bone).

    The candidates are, per effector slot ``k`` in turn and per joint ``seg[i]`` of its
    branch from the top (:func:`branch_segments`), the bend of joint ``m`` (``seg[i + 1]``,
    or ``seg[i]`` for the last bone) when the bones from ``seg[i]`` down are straight and
    point at the target."""
    bones, pairs, cand, need = [], [], [], []
    for k, seg in enumerate(branch_segments(topo)):
        if len(seg) < 2:  # the root as an effector: no bone to bend
            continue
        b0, p0 = len(bones), len(pairs)
        bones += [(seg[j], seg[j + 1]) for j in range(len(seg) - 1)]
        pairs += [(b0 + j, b0 + j + 1) for j in range(len(seg) - 2)]
        for i in range(max(len(seg) - 2, 1)):
            cand.append((k, seg[i], b0 + i, seg[i + 1] if len(seg) - i > 2 else seg[i]))
            need.append(range(p0 + i, p0 + len(seg) - 2))  # the bones below seg[i], pairwise parallel
    if not cand:
        return None
    C = len(cand)
    slot, joint, bone, m = (np.asarray([c[f] for c in cand]) for f in range(4))
    needs = np.zeros((C, max(len(pairs), 1)), bool)
    for c, r in enumerate(need):
        needs[c, list(r)] = True
    earlier = (slot[:, None] == slot[None, :]) & (np.arange(C)[None, :] < np.arange(C)[:, None])
    moved = sorted(set(m.tolist()))
    per = [[c for c in range(C) if m[c] == j] for j in moved]
    depth = max(len(p) for p in per)
    compose = np.asarray([p + [C] * (depth - len(p)) for p in per])  # C: the identity row
    parent = np.asarray([topo.parents[j] if j > 0 else 0 for j in moved])
    return BendPlan(bones=np.asarray(bones).T, pairs=np.asarray(pairs, dtype=int).reshape(-1, 2).T, slot=slot,
                    joint=joint, bone=bone, needs=needs, earlier=earlier, moved=np.asarray(moved), compose=compose,
                    parent=parent)


def bend_straight(topo, L, P, G, targets, tol):
    """Bend the straight branches of a tree that lie on the line of their target.

    Where the lower part of an effector's branch (see :func:`branch_segments`), from
    some joint ``b`` down to the effector, lies on the line from ``b`` to the effector's
    target, and the effector is not yet within ``tol``, the joint just below the
    highest such ``b`` is turned by ``SYMMETRY_BREAK_ANGLE`` about an axis perpendicular
    to the line (as :func:`break_symmetry_chain` does for chains).  Vectorised over the
    branches' joints (a few operations on ``(..., C, 3)`` arrays, not one per joint).

    Args:
      topo: static ``Topology``.
      L, G: ``(..., J, 4)`` local rotations and their world frames; P: ``(..., J, 3)``.
      targets: ``(..., E, 3)``; tol: the effector error (m) that counts as reached.

    Returns:
      ``(..., J, 4)`` local rotations, broadcast to the targets' batch; the caller redoes FK.
    """
    plan = _bend_plan(topo)
    batch = jnp.broadcast_shapes(L.shape[:-2], P.shape[:-2], targets.shape[:-2])
    L = jnp.broadcast_to(L, batch + L.shape[-2:])
    if plan is None:
        return L
    q = functools.partial(_quat.unstack, axis=-1)

    def at(x, idx):
        return jnp.take(x, idx, axis=-2)

    def parallel(u, v):
        return _quat.safe_norm(_quat.cross(u, v)) <= 1e-6 * _quat.safe_norm(u) * _quat.safe_norm(v)

    bones = at(P, plan.bones[1]) - at(P, plan.bones[0])  # (..., nb, 3)
    par = parallel(q(at(bones, plan.pairs[0])), q(at(bones, plan.pairs[1])))  # (..., np)
    if par.shape[-1] == 0:
        par = jnp.ones(par.shape[:-1] + (1,), bool)
    straight = jnp.all(par[..., None, :] | ~plan.needs, axis=-1)  # (..., C)
    bone = q(at(bones, plan.bone))
    reached = _quat.safe_norm(q(at(P, np.asarray(topo.effectors)) - targets)) <= tol  # (..., E)
    raw = (straight & parallel(bone, q(at(targets, plan.slot) - at(P, plan.joint)))
           & ~jnp.take(reached, plan.slot, axis=-1))
    pick = raw & ~jnp.any(raw[..., None, :] & plan.earlier, axis=-1)  # the highest per branch
    r = _quat.where(pick, _bend(_quat.perpendicular(bone)), _quat.identity(pick.shape, L.dtype))
    r = tuple(jnp.concatenate([c, jnp.ones_like(c[..., :1]) if i == 0 else jnp.zeros_like(c[..., :1])], axis=-1)
              for i, c in enumerate(r))  # and the identity row C
    R = _quat.identity(plan.compose.shape[:1], L.dtype)
    for s in range(plan.compose.shape[1]):  # two picks on one joint: turned in the branches' order
        R = _quat.mul(tuple(jnp.take(c, plan.compose[:, s], axis=-1) for c in r), R)
    any_pick = jnp.any(jnp.take(jnp.concatenate([pick, jnp.zeros_like(pick[..., :1])], axis=-1), plan.compose,
                                axis=-1), axis=-1)
    gp = q(jnp.where((plan.moved == 0)[:, None], jnp.asarray([1.0, 0.0, 0.0, 0.0], L.dtype), at(G, plan.parent)))
    Lm = q(at(L, plan.moved))
    turned = _quat.mul(_quat.conj(gp), _quat.mul(R, _quat.mul(gp, Lm)))
    return L.at[..., plan.moved, :].set(_quat.stack(_quat.where(any_pick, turned, Lm), axis=-1))
