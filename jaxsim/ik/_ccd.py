"""Cyclic coordinate descent (CCD): one sweep, tip to root.

Each joint ``i`` (from ``J-2`` down to the root) turns its *global* frame by the
shortest arc ``r`` that swings the end effector onto the ray from joint ``i`` to the
target, and the local rotation becomes ``L_i = G_{i-1}^{-1} * r * G_i`` (Wang & Chen 1991;
the lab's CCD).  The global frames ``G`` come from FK at the start of the sweep; a joint
only changes frames below it, so ``G_{i-1}`` and ``G_i`` are still current when joint
``i`` is visited and only the end effector needs updating as the sweep goes up.
"""

from __future__ import annotations

import jax.numpy as jnp

from . import _joints, _quat
from ._fk import fk_joints

#: The batched sweep renormalises its frames by one Newton step (no ``rsqrt``, which XLA
#: then fuses with the products before it) from this many elements up, by ``rsqrt``
#: below.  Interleaved against each other (CCD, 10 sweeps, float32, 6 joints), the Newton
#: step ran 0.58 against 0.80 M solves/s at 256 elements and 1.06 against 1.20 at 1024
#: (fused, XLA recomputes the products in every consumer), and 1.42 against 1.31 at 4096,
#: 1.39 against 1.18 at 100k (memory-bound: fewer fusions win).
NEWTON_RENORM_MIN_BATCH = 4096


def ccd_sweep(offsets, target, local, positions, frames, batch_shape, *, unroll: bool):
    """One CCD sweep on per-joint containers.

    Args:
      offsets: ``(J, 3)``.
      target: vector tuple over ``batch_shape``.
      local, positions, frames: containers of local rotations and their FK.

    Returns:
      ``(local, positions, frames)`` after the sweep, the last two by FK of the new
      local rotations, so the error the loop sees is that of the returned pose.
    """
    J = offsets.shape[0]
    ident = _quat.identity(batch_shape, offsets.dtype)

    def body(i, c):
        L, end = c
        p = _joints.get(positions, i)
        r = _quat.from_two_vectors(_quat.sub(end, p), _quat.sub(target, p))
        end = _quat.add(p, _quat.rotate(r, _quat.sub(end, p)))
        if unroll:
            g_parent = ident if i == 0 else frames[i - 1]
        else:
            g_parent = _quat.where(i > 0, _joints.get(frames, jnp.maximum(i - 1, 0)), ident)
        g = _quat.mul(r, _joints.get(frames, i))
        # renormalised so rounding cannot compound through FK over many sweeps
        L = _joints.put(L, i, _quat.renormalize(_quat.mul(_quat.conj(g_parent), g)))
        return L, end

    L, _ = _joints.loop(0, J - 1, body, (local, _joints.get(positions, J - 1)), unroll=unroll, reverse=True)
    P, G = fk_joints(offsets, L, batch_shape, unroll=unroll)
    return L, P, G


def ccd_sweep_frames(offsets, target, frames, root):
    """One CCD sweep for large batches, on the global frames alone.

    The same sweep as :func:`ccd_sweep`, carried as the ``J`` global frames instead of
    local rotations, positions and frames (24 arrays instead of 66 for six joints):
    joint positions come from the frames, the arcs ``r_i`` are taken tip to root while
    the end effector is swung along, and the new frames are ``G'_i = r_0 r_1 ... r_i G_i``
    (a joint's turn carries every frame below it).  The local rotations
    ``L_i = G_{i-1}^{-1} G_i`` are rebuilt once, after the last sweep
    (:func:`locals_from_frames`).  The arcs are :func:`_quat.arc_lean`: where the end
    effector and the target lie exactly opposite about a joint, that joint does not turn
    in this sweep (the joints above it still do), where :func:`ccd_sweep` turns it half
    a turn.

    Args:
      offsets: ``(J, 3)``.
      target, root: vector tuples.
      frames: list of ``J`` unit quaternion tuples.

    Returns:
      ``(frames, end_sq_error)``: the new frames, renormalised (from
      ``NEWTON_RENORM_MIN_BATCH`` elements up by one Newton step,
      :func:`_quat.renormalize_near_unit`: the frames enter unit to rounding and the
      arcs are unit to rounding), and ``|end - target|^2``.
    """
    J = offsets.shape[0]
    P = [root]
    for k in range(1, J):
        P.append(_quat.add(P[k - 1], _quat.rotate(frames[k - 1], _quat.unstack(offsets[k]))))
    end = P[J - 1]
    arcs = [None] * (J - 1)
    for i in range(J - 2, -1, -1):
        a = _quat.sub(end, P[i])
        arcs[i] = _quat.arc_lean(a, _quat.sub(target, P[i]))
        end = _quat.add(P[i], _quat.rotate(arcs[i], a))
    big = jnp.size(frames[0][0]) >= NEWTON_RENORM_MIN_BATCH  # the loop carries full-batch frames
    renorm = _quat.renormalize_near_unit if big else _quat.renormalize
    new, C = [], None
    for i in range(J - 1):
        C = arcs[i] if C is None else _quat.mul(C, arcs[i])
        new.append(renorm(_quat.mul(C, frames[i])))
    new.append(renorm(_quat.mul(C, frames[J - 1])))
    return new, _quat.sqnorm(_quat.sub(end, target))


def locals_from_frames(frames):
    """Local rotations ``L_0 = G_0``, ``L_i = G_{i-1}^{-1} G_i`` (renormalised) of a list of frames."""
    out = [_quat.renormalize(frames[0])]
    for i in range(1, len(frames)):
        out.append(_quat.renormalize(_quat.mul(_quat.conj(frames[i - 1]), frames[i])))
    return out
