"""FABRIK (Aristidou & Lasenby 2011, Algorithm 1): positions first, rotations rebuilt after.

One sweep is a backward pass (pin the end on the target, walk to the root) and a forward
pass (pin the root, walk to the end); each step puts a joint on the line to its
neighbour at the bone's length.  An unreachable target is answered up front by the
paper's straight line towards the target (one sweep).
"""

from __future__ import annotations

from jax import lax

from . import _joints, _quat


def fabrik_sweep(positions, target, root, lengths, fallback, *, unroll: bool):
    """One backward + forward FABRIK pass.

    Args:
      positions: container of ``J`` joint positions (vector tuples).
      target, root: vector tuples (root may broadcast).
      lengths: ``(J-1,)`` bone lengths.
      fallback: unit vector tuple used where two joints coincide.

    Returns:
      New positions in the same container type.
    """
    J = lengths.shape[0] + 1

    def backward(i, P):
        child = _joints.get(P, i + 1)
        u = _quat.normalize(_quat.sub(_joints.get(P, i), child), fallback)
        return _joints.put(P, i, _quat.add(child, _quat.scale(lengths[i], u)))

    def forward(i, P):
        parent = _joints.get(P, i - 1)
        u = _quat.normalize(_quat.sub(_joints.get(P, i), parent), fallback)
        return _joints.put(P, i, _quat.add(parent, _quat.scale(lengths[i - 1], u)))

    P = _joints.put(positions, J - 1, target)
    P = _joints.loop(0, J - 1, backward, P, unroll=unroll, reverse=True)
    P = _joints.put(P, 0, root)
    return _joints.loop(1, J, forward, P, unroll=unroll)


def fabrik_sweep_lean(joints, target, root, lengths, bias):
    """One backward + forward FABRIK pass, written for large batches.

    The same pass as :func:`fabrik_sweep` on an unrolled chain, with what a batched
    sweep does not need taken out: the root is not carried (the forward pass pins it),
    so joint 0 is not placed in the backward pass either, and each bone direction is
    ``d * rsqrt(d.d)`` with ``d`` offset by ``bias``, a vector of length ``tiny`` along
    the fallback direction, instead of a zero test and a ``where`` per joint: where two
    joints coincide the direction is the fallback, elsewhere the offset is far below
    rounding.

    Args:
      joints: list of ``J-1`` vector tuples, joints ``1..J-1``.
      target, root: vector tuples.
      lengths: ``(J-1,)`` bone lengths.
      bias: vector tuple, ``tiny * fallback``.

    Returns:
      The new list of ``J-1`` joints.
    """
    n = len(joints)
    new = list(joints)

    def place(moving, anchor, length):
        d = tuple(m - a + b for m, a, b in zip(moving, anchor, bias))
        s = length * lax.rsqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        return tuple(a + s * c for a, c in zip(anchor, d))

    nxt = new[n - 1] = target
    for i in range(n - 1, 0, -1):  # joint i (stored at i - 1), towards joint i + 1
        nxt = new[i - 1] = place(new[i - 1], nxt, lengths[i])
    prev = root
    for i in range(1, n + 1):  # joint i, from joint i - 1
        prev = new[i - 1] = place(new[i - 1], prev, lengths[i - 1])
    return new


def straight_towards(root, target, lengths, fallback):
    """Joint positions (a list of vector tuples) of the chain stretched from ``root`` towards ``target``."""
    ray = _quat.normalize(_quat.sub(target, root), fallback)
    out, acc = [root], 0.0
    for i in range(lengths.shape[0]):
        acc = acc + lengths[i]
        out.append(_quat.add(root, _quat.scale(acc, ray)))
    return out


def rotations_from_positions(offsets, local0, positions, batch_shape, *, unroll: bool):
    """Local rotations whose FK reproduces ``positions``, changed minimally from ``local0``.

    Walks down the chain.  Joint ``i``'s bone points along ``c = R(L0_i) o_{i+1}`` in its
    parent's frame when it keeps its old local rotation ``L0_i``; it should point along
    the wanted bone ``P_{i+1} - P_i`` taken into the parent's *new* frame,
    ``w = R(g_{i-1})^T (P_{i+1} - P_i)``.  The new local rotation is the shortest arc
    from ``c`` to ``w`` times ``L0_i`` (the shortest arc in world space, seen from the
    parent), by :func:`_quat.arc_lean` with the half-turn about a perpendicular of ``c``
    where ``w`` is opposite to it.  With a start pose shared by the batch, ``c`` and its
    perpendicular are one vector per joint.
    The end joint (no child bone) keeps its old local rotation.

    Args:
      offsets: ``(J, 3)``.
      local0: container of the ``J`` local rotations the positions were started from.
      positions: container of ``J`` joint positions with the chain's bone lengths.

    Returns:
      Container of ``J`` local rotations.
    """
    J = offsets.shape[0]
    ident = _quat.identity(batch_shape, offsets.dtype)

    def body(i, c):
        L, g_parent = c
        l0 = _joints.get(local0, i)
        bone_rest = _quat.rotate(l0, _quat.unstack(offsets[i + 1]))
        want = _quat.sub(_joints.get(positions, i + 1), _joints.get(positions, i))
        want = _quat.rotate(_quat.conj(g_parent), want)
        arc = _quat.arc_lean(bone_rest, want, _quat.perpendicular(bone_rest))
        local = _quat.renormalize(_quat.mul(arc, l0))
        return _joints.put(L, i, local), _quat.mul(g_parent, local)

    L, _ = _joints.loop(0, J - 1, body, (local0, ident), unroll=unroll)
    return L
