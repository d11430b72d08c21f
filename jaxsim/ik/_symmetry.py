"""Symmetric poses: a chain lying on the line through its root and its target.

Neither CCD nor FABRIK can leave that line by itself (every update is a rotation about a
zero axis, or a move along the line), so such poses are bent first (FABRIK paper, §5.4).
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from .._geometry import quat as _quat

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


def break_symmetry_tree(topo, offsets, local, positions, frames, targets, tol):
    """Bend the straight branches of a tree that lie on the line of their target.

    Where the lower part of an effector's branch (see :func:`branch_segments`), from
    some joint ``b`` down to the effector, lies on the line from ``b`` to the effector's
    target, and the effector is not yet within ``tol``, the joint just below the
    highest such ``b`` is turned by ``SYMMETRY_BREAK_ANGLE`` about an axis perpendicular
    to the line (as :func:`break_symmetry_chain` does for chains).  Returns the new list of
    local rotations; the caller redoes FK.
    """
    def parallel(u, v):
        return _quat.safe_norm(_quat.cross(u, v)) <= 1e-6 * _quat.safe_norm(u) * _quat.safe_norm(v)

    local = list(local)
    for k, seg in enumerate(branch_segments(topo)):
        if len(seg) < 2:  # the root as an effector: no bone to bend
            continue
        bones = [_quat.sub(positions[seg[j + 1]], positions[seg[j]]) for j in range(len(seg) - 1)]
        # straight_below[i]: the bones from seg[i] down to the effector are all parallel
        straight_below = [None] * len(bones)
        straight_below[-1] = True
        for i in range(len(bones) - 2, -1, -1):
            straight_below[i] = straight_below[i + 1] & parallel(bones[i], bones[i + 1])
        taken = _quat.safe_norm(_quat.sub(positions[seg[-1]], targets[k])) <= tol
        for i in range(max(len(seg) - 2, 1)):
            to_target = _quat.sub(targets[k], positions[seg[i]])
            pick = straight_below[i] & parallel(bones[i], to_target) & ~taken
            taken = taken | pick
            m = seg[i + 1] if len(seg) - i > 2 else seg[i]
            r = _bend(_quat.perpendicular(bones[i]))
            gp = frames[topo.parents[m]] if m > 0 else None
            turned = _quat.mul(r, local[m] if gp is None else _quat.mul(gp, local[m]))
            lm = turned if gp is None else _quat.mul(_quat.conj(gp), turned)
            local[m] = _quat.where(pick, lm, local[m])
    return local
