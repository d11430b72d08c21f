"""Forward kinematics on joint trees, by the lab's recursion with "parent" read from ``parents``::

    G_0 = L_0,  P_0 = offsets[0];   G_i = G_p L_i,  P_i = P_p + G_p offsets[i]   (p = parents[i])
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from . import _quat
from ._chain import Pose


def fk_tree(parents, offsets, local, joints=None):
    """FK on lists of component tuples.

    Args:
      parents: static parent tuple.
      offsets: ``(J, 3)``.
      local: list of ``J`` local quaternion tuples (any common batch shape).
      joints: the joints to compute (an ancestor-closed increasing tuple); default all.
        Other entries of the outputs are ``None``.

    Returns:
      ``(positions, frames)``: lists of ``J`` vector and quaternion tuples.
    """
    J = len(parents)
    joints = range(J) if joints is None else joints
    P, G = [None] * J, [None] * J
    for i in joints:
        if i == 0:
            P[0], G[0] = _quat.unstack(offsets[0]), local[0]
            continue
        p = parents[i]
        P[i] = _quat.add(P[p], _quat.rotate(G[p], _quat.unstack(offsets[i])))
        G[i] = _quat.mul(G[p], local[i])
    return P, G


def skeleton_fk(skeleton, rotations: jax.Array | None = None) -> Pose:
    """Forward kinematics of a ``Skeleton``: ``rotations (..., J, 4)`` -> ``Pose`` ``(..., J, 3)``, ``(..., J, 4)``.

    Rotations are normalised first (a zero quaternion is the identity), as for chains.
    """
    if rotations is None:
        rotations = skeleton.rest_rotations()
    rotations = jnp.asarray(rotations, skeleton.offsets.dtype)
    J = skeleton.num_joints
    if rotations.shape[-2:] != (J, 4):
        raise ValueError(f"rotations must have shape (..., {J}, 4), got {rotations.shape}")
    rotations = _quat.unit_quaternions(rotations)
    batch = rotations.shape[:-2]
    local = [_quat.unstack(rotations[..., i, :], axis=-1) for i in range(J)]
    P, G = fk_tree(skeleton.parents, skeleton.offsets, local)
    P = [tuple(jnp.broadcast_to(c, batch) for c in p) for p in P]
    return Pose(positions=jnp.stack([_quat.stack(p, axis=-1) for p in P], axis=-2),
                rotations=jnp.stack([_quat.stack(g, axis=-1) for g in G], axis=-2))
