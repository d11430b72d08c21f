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
