"""FABRIK (Aristidou & Lasenby 2011, Algorithm 1): positions first, rotations rebuilt after.

One sweep is a backward pass (pin the end on the target, walk to the root) and a forward
pass (pin the root, walk to the end); each step puts a joint on the line to its
neighbour at the bone's length.  An unreachable target is answered up front by the
paper's straight line towards the target (one sweep).
"""

from __future__ import annotations

import jax.numpy as jnp

from . import _joints, _quat
from ._fk import fk_component_first


def fabrik_sweep(positions, target, root, lengths, *, unroll: bool):
    """One backward + forward FABRIK pass.

    Args:
      positions: ``(J, 3, *B)`` joint positions (stacked or per-joint list).
      target, root: ``(3, *B)`` (root may broadcast).
      lengths: ``(J-1, 1, ...)`` bone lengths, broadcastable per joint.

    Returns:
      New positions in the same container type.
    """
    P = positions
    J = len(P) if isinstance(P, list) else P.shape[0]

    def backward(i, P):
        child = _joints.get(P, i + 1)
        d = _joints.get(P, i) - child
        # A joint sitting exactly on its child keeps the child's old direction to it.
        u = _quat.normalize(d, _quat.perpendicular(target - root))
        return _joints.put(P, i, child + lengths[i] * u)

    def forward(i, P):
        parent = _joints.get(P, i - 1)
        d = _joints.get(P, i) - parent
        u = _quat.normalize(d, _quat.perpendicular(target - root))
        return _joints.put(P, i, parent + lengths[i - 1] * u)

    P = _joints.put(P, J - 1, jnp.broadcast_to(target, _joints.get(P, J - 1).shape))
    P = _joints.loop(0, J - 1, backward, P, unroll=unroll, reverse=True)
    P = _joints.put(P, 0, jnp.broadcast_to(root, _joints.get(P, 0).shape))
    return _joints.loop(1, J, forward, P, unroll=unroll)


def straight_towards(root, target, lengths, num_joints: int, fallback):
    """Joint positions of the chain stretched along the ray from ``root`` to ``target``.

    Returns a per-joint list of ``(3, *B)`` arrays.
    """
    ray = _quat.normalize(target - root, fallback)
    out, acc = [jnp.broadcast_to(root, ray.shape)], 0.0
    for i in range(num_joints - 1):
        acc = acc + lengths[i]
        out.append(root + acc * ray)
    return out


def rotations_from_positions(offsets, local0, positions, *, unroll: bool):
    """Local rotations whose FK reproduces ``positions``, changed minimally from ``local0``.

    Walks down the chain: joint ``i``'s candidate global frame is its parent's *new*
    frame times its old local rotation; the shortest arc from the bone that frame
    predicts to the bone in ``positions`` corrects it.  The end joint (no child bone)
    keeps its old local rotation.

    Args:
      offsets: ``(J, 3)``.
      local0: ``(J, 4, *B)`` local rotations the positions were started from.
      positions: ``(J, 3, *B)`` target joint positions with the chain's bone lengths.

    Returns:
      ``(J, 4, *B)`` local rotations.
    """
    nb = local0.ndim - 2
    off = jnp.reshape(offsets, offsets.shape + (1,) * nb).astype(local0.dtype)
    J = local0.shape[0]
    L0 = _joints.split(local0, unroll)
    P = _joints.split(positions, unroll)
    ident = _quat.identity(local0.shape[2:], local0.dtype)

    def body(i, c):
        L, g_parent = c
        g = _quat.mul(g_parent, _joints.get(L0, i))
        bone_now = _quat.rotate(g, off[i + 1])
        bone_want = _joints.get(P, i + 1) - _joints.get(P, i)
        g = _quat.renormalize(_quat.mul(_quat.from_two_vectors(bone_now, bone_want), g))
        L = _joints.put(L, i, _quat.mul(_quat.conj(g_parent), g))
        return L, g

    L, _ = _joints.loop(0, J - 1, body, (L0, ident), unroll=unroll)
    return _joints.stack(L)
