"""Symmetric poses: a chain lying on the line through its root and its target.

Neither CCD nor FABRIK can leave that line by itself (every update is a rotation about a
zero axis, or a move along the line), so such poses are bent first (FABRIK paper, §5.4).
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from . import _quat

#: Bend applied to a chain lying on the line of its target (FABRIK paper, section 5.4).
SYMMETRY_BREAK_ANGLE = 0.1


def break_symmetry(local, positions, frames, target, reach, done, batch_shape):
    """Bend a chain that lies on the line through its root and target.

    Neither CCD nor FABRIK can leave that line by itself (every update is a rotation
    about a zero axis, or a move along the line).  Such poses get joint 1 (or the root of
    a one-bone chain) turned by ``SYMMETRY_BREAK_ANGLE`` about an axis perpendicular to
    the line; other poses are returned unchanged.  Works on stacked ``(J, C, *B)``
    arrays ``local``, ``positions``, ``frames``; ``target`` is a vector tuple.
    """
    J = local.shape[0]
    root = _quat.unstack(positions[0])
    to_target = _quat.sub(target, root)
    chain_dir = _quat.normalize(_quat.sub(_quat.unstack(positions[J - 1]), root), _quat.perpendicular(to_target))
    ray = _quat.normalize(to_target, chain_dir)
    rel = _quat.unstack(positions - positions[:1], axis=1)  # tuple of (J, *B)
    ray_j = tuple(c[None] for c in ray)
    off_line = jnp.max(_quat.safe_norm(_quat.cross(rel, ray_j)), axis=0)
    need = (off_line <= 1e-6 * reach) & ~done
    m = 1 if J > 2 else 0
    half = 0.5 * SYMMETRY_BREAK_ANGLE
    r = (jnp.full(batch_shape, np.cos(half), local.dtype), *_quat.scale(float(np.sin(half)), _quat.perpendicular(ray)))
    g_parent = _quat.unstack(frames[m - 1]) if m > 0 else _quat.identity(batch_shape, local.dtype)
    lm = _quat.mul(_quat.conj(g_parent), _quat.mul(r, _quat.mul(g_parent, _quat.unstack(local[m]))))
    return jnp.where(need, local.at[m].set(_quat.stack(lm)), local)


def break_symmetry_lists(local, positions, frames, target, reach, done):
    """:func:`break_symmetry` on per-joint lists, without a second FK over the batch.

    Turning joint ``m``'s global frame by ``r`` turns every frame below it and swings
    every joint below it about joint ``m``: ``G_k <- r G_k`` (``k >= m``),
    ``P_k <- P_m + r (P_k - P_m)`` (``k > m``), applied where the pose needs it.  Entries
    may have no batch axis (a start pose shared by the batch); the bent ones gain it.
    """
    J = len(local)
    root = positions[0]
    to_target = _quat.sub(target, root)
    chain_dir = _quat.normalize(_quat.sub(positions[J - 1], root), _quat.perpendicular(to_target))
    ray = _quat.normalize(to_target, chain_dir)
    off_line = functools.reduce(jnp.maximum, [_quat.safe_norm(_quat.cross(_quat.sub(p, root), ray)) for p in positions])
    need = (off_line <= 1e-6 * reach) & ~done
    m = 1 if J > 2 else 0
    half = 0.5 * SYMMETRY_BREAK_ANGLE
    axis = _quat.perpendicular(ray)
    r = (jnp.full_like(axis[0], np.cos(half)), *_quat.scale(float(np.sin(half)), axis))
    g_parent = frames[m - 1] if m > 0 else _quat.identity((), local[0][0].dtype)
    lm = _quat.mul(_quat.conj(g_parent), _quat.mul(r, _quat.mul(g_parent, local[m])))
    local, positions, frames = list(local), list(positions), list(frames)
    local[m] = _quat.where(need, lm, local[m])
    pm = positions[m]
    for k in range(m + 1, J):
        positions[k] = _quat.where(need, _quat.add(pm, _quat.rotate(r, _quat.sub(positions[k], pm))), positions[k])
    for k in range(m, J):
        frames[k] = _quat.where(need, _quat.mul(r, frames[k]), frames[k])
    return local, positions, frames
