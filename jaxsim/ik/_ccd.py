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
from ._fk import fk_component_first


def ccd_sweep(offsets, target, local, positions, frames, *, unroll: bool):
    """One CCD sweep on component-first arrays.

    Args:
      offsets: ``(J, 3)``.
      target: ``(3, *B)``.
      local: ``(J, 4, *B)`` local rotations at the start of the sweep.
      positions, frames: ``(J, 3, *B)``, ``(J, 4, *B)``: FK of ``local``.

    Returns:
      ``(local, positions, frames)`` after the sweep, the last two by FK of the new
      local rotations, so the error seen by the loop is that of the returned pose.
    """
    J = local.shape[0]
    P, G = _joints.split(positions, unroll), _joints.split(frames, unroll)
    L = _joints.split(local, unroll)
    ident = _quat.identity(target.shape[1:], local.dtype)

    def body(i, c):
        L, end = c
        p = _joints.get(P, i)
        r = _quat.from_two_vectors(end - p, target - p)
        end = p + _quat.rotate(r, end - p)
        if unroll:
            g_parent = ident if i == 0 else G[i - 1]
        else:
            g_parent = jnp.where(i > 0, G[jnp.maximum(i - 1, 0)], ident)
        L = _joints.put(L, i, _quat.mul(_quat.conj(g_parent), _quat.mul(r, _joints.get(G, i))))
        return L, end

    L, _ = _joints.loop(0, J - 1, body, (L, _joints.get(P, J - 1)), unroll=unroll, reverse=True)
    L = _quat.renormalize(_joints.stack(L), axis=1)
    P, G = fk_component_first(offsets, L, unroll=unroll)
    return L, P, G
