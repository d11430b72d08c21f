"""Forward kinematics by the lab's recursion.

``G_0 = L_0``, ``P_0 = offsets[0]``, and for ``i >= 1``::

    G_i = G_{i-1} * L_i                      (GlobalRotation(child) = GlobalRotation(parent) * LocalRotation(child))
    P_i = P_{i-1} + G_{i-1} * offsets[i]     (GlobalPosition(child) = GlobalPosition(parent) + GlobalRotation(parent) * LocalOffset(child))
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from . import _joints, _quat
from ._chain import Chain, Pose
from ._skeleton import Skeleton
from ._tree_fk import skeleton_fk


def fk_joints(offsets, local, batch_shape, *, unroll: bool):
    """FK on per-joint containers (see ``_joints``).

    Args:
      offsets: ``(J, 3)`` chain offsets.
      local: container of ``J`` local rotations (quaternion tuples over ``batch_shape``).
      batch_shape: the batch shape ``B`` of every component array.
      unroll: container kind (list if True, stacked ``(J, C, *B)`` array if False).

    Returns:
      ``(positions, globals)`` containers of the same kind.
    """
    J = offsets.shape[0]
    dtype = offsets.dtype
    root = tuple(jnp.broadcast_to(c, batch_shape) for c in _quat.unstack(offsets[0]))
    if unroll:
        P, G = [root] * J, [local[0]] * J
    else:
        P = jnp.zeros((J, 3) + tuple(batch_shape), dtype)
        P = _joints.put(P, 0, root)
        G = local

    def body(i, c):
        P, G = c
        g_parent = _joints.get(G, i - 1)
        p = _quat.add(_joints.get(P, i - 1), _quat.rotate(g_parent, _quat.unstack(offsets[i])))
        P = _joints.put(P, i, p)
        G = _joints.put(G, i, _quat.mul(g_parent, _joints.get(local, i)))
        return P, G

    return _joints.loop(1, J, body, (P, G), unroll=unroll)


def fk(chain: Chain, rotations: jax.Array | None = None, *, unroll: bool | None = None) -> Pose:
    """Forward kinematics.

    Args:
      chain: a ``Chain`` with ``offsets (J, 3)``, or a ``Skeleton`` (the recursion with
        "parent" read from ``parents``; ``unroll`` does not apply).
      rotations: ``(..., J, 4)`` local rotations as quaternions (w, x, y, z); ``None`` is
        the rest pose.  Any leading batch shape is allowed.  They are normalised first
        (``q / |q|``, and a zero quaternion is the identity), so bone lengths are kept
        whatever the scale of ``q``.
      unroll: unroll the joint loop (default: ``J <= 16`` and a batch of >= 256).

    Returns:
      ``Pose`` with global ``positions (..., J, 3)`` and ``rotations (..., J, 4)``.
    """
    if isinstance(chain, Skeleton):
        return skeleton_fk(chain, rotations)
    if rotations is None:
        rotations = chain.rest_rotations()
    rotations = jnp.asarray(rotations, dtype=chain.offsets.dtype)
    J = chain.num_joints
    if rotations.shape[-2:] != (J, 4):
        raise ValueError(f"rotations must have shape (..., {J}, 4), got {rotations.shape}")
    rotations = _quat.unit_quaternions(rotations)
    unroll = _joints.unrolled(J, unroll, int(np.prod(rotations.shape[:-2])))
    local = _joints.split(jnp.moveaxis(rotations, (-2, -1), (0, 1)), unroll)
    P, G = fk_joints(chain.offsets, local, rotations.shape[:-2], unroll=unroll)
    return Pose(
        positions=jnp.moveaxis(_joints.stack(P), (0, 1), (-2, -1)),
        rotations=jnp.moveaxis(_joints.stack(G), (0, 1), (-2, -1)),
    )
