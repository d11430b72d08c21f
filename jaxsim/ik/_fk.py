"""Forward kinematics by the lab's recursion.

``G_0 = L_0``, ``P_0 = offsets[0]``, and for ``i >= 1``::

    G_i = G_{i-1} * L_i                      (GlobalRotation(child) = GlobalRotation(parent) * LocalRotation(child))
    P_i = P_{i-1} + G_{i-1} * offsets[i]     (GlobalPosition(child) = GlobalPosition(parent) + GlobalRotation(parent) * LocalOffset(child))
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from . import _joints, _quat
from ._chain import Chain, Pose


def expand(x, nbatch: int):
    """Append ``nbatch`` singleton axes so ``x`` broadcasts against component-first batches."""
    return jnp.reshape(x, x.shape + (1,) * nbatch)


def fk_component_first(offsets, local, *, unroll: bool):
    """FK on component-first arrays.

    Args:
      offsets: ``(J, 3)`` chain offsets.
      local: ``(J, 4, *B)`` local rotations.
      unroll: unroll the joint loop in Python.

    Returns:
      ``positions (J, 3, *B)`` and ``globals (J, 4, *B)``.
    """
    nb = local.ndim - 2
    off = expand(offsets, nb).astype(local.dtype)
    J = local.shape[0]
    L = _joints.split(local, unroll)
    P = _joints.split(jnp.broadcast_to(off, (J, 3) + local.shape[2:]), unroll)
    G = _joints.put(L, 0, _joints.get(L, 0))

    def body(i, c):
        P, G = c
        g_parent = _joints.get(G, i - 1)
        P = _joints.put(P, i, _joints.get(P, i - 1) + _quat.rotate(g_parent, off[i]))
        G = _joints.put(G, i, _quat.mul(g_parent, _joints.get(L, i)))
        return P, G

    P, G = _joints.loop(1, J, body, (P, G), unroll=unroll)
    return _joints.stack(P), _joints.stack(G)


def fk(chain: Chain, rotations: jax.Array | None = None, *, unroll: bool | None = None) -> Pose:
    """Forward kinematics.

    Args:
      chain: the chain, with ``offsets (J, 3)``.
      rotations: ``(..., J, 4)`` local unit quaternions (w, x, y, z); ``None`` is the rest
        pose.  Any leading batch shape is allowed.
      unroll: unroll the joint loop (default: for ``J <= 16``).

    Returns:
      ``Pose`` with global ``positions (..., J, 3)`` and ``rotations (..., J, 4)``.
    """
    if rotations is None:
        rotations = chain.rest_rotations()
    rotations = jnp.asarray(rotations, dtype=chain.offsets.dtype)
    J = chain.num_joints
    if rotations.shape[-2:] != (J, 4):
        raise ValueError(f"rotations must have shape (..., {J}, 4), got {rotations.shape}")
    local = jnp.moveaxis(rotations, (-2, -1), (0, 1))
    P, G = fk_component_first(chain.offsets, local, unroll=_joints.unrolled(J, unroll))
    return Pose(
        positions=jnp.moveaxis(P, (0, 1), (-2, -1)), rotations=jnp.moveaxis(G, (0, 1), (-2, -1))
    )
