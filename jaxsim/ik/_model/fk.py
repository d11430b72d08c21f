"""Forward kinematics by the lab's recursion, with "parent" read from ``parents``::

    G_0 = L_0,  P_0 = offsets[0];   G_i = G_p L_i,  P_i = P_p + G_p offsets[i]   (p = parents[i])

(``GlobalRotation(child) = GlobalRotation(parent) * LocalRotation(child)``,
``GlobalPosition(child) = GlobalPosition(parent) + GlobalRotation(parent) * LocalOffset(child)``.)
A tree goes one tree level at a time, all of a level's joints at once
(``stacked.fk_stacked``); a chain may also run the recursion as a ``fori_loop`` over
stacked arrays (:func:`fk_joints`, see ``joints``), whose compile time does not grow with ``J``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..._dataclass import pytree_dataclass
from ..._validate import array_like
from ..._geometry import quat as _quat
from . import joints as _joints
from .skeleton import chain_parents
from .stacked import fk_stacked


@pytree_dataclass
class Pose:
    """Global joint frames from forward kinematics.

    Attributes:
      positions: ``(..., J, 3)`` world positions of the joints.
      rotations: ``(..., J, 4)`` world (global) rotations, unit quaternions (w, x, y, z).
    """

    positions: jax.Array
    rotations: jax.Array


def fk_joints(offsets, local, batch_shape, *, unroll: bool):
    """FK of a chain on per-joint containers (see ``joints``).

    Args:
      offsets: ``(J, 3)`` chain offsets.
      local: container of ``J`` local rotations (quaternion tuples over ``batch_shape``).
      batch_shape: the batch shape ``B`` of every component array.
      unroll: container kind (list if True, stacked ``(J, C, *B)`` array if False).

    Returns:
      ``(positions, globals)`` containers of the same kind.
    """
    J = offsets.shape[0]
    root = tuple(jnp.broadcast_to(c, batch_shape) for c in _quat.unstack(offsets[0]))
    if unroll:
        P, G = [root] * J, [local[0]] * J
    else:
        P = _joints.put(jnp.zeros((J, 3) + tuple(batch_shape), offsets.dtype), 0, root)
        G = local

    def body(i, c):
        P, G = c
        g_parent = _joints.get(G, i - 1)
        p = _quat.add(_joints.get(P, i - 1), _quat.rotate(g_parent, _quat.unstack(offsets[i])))
        return _joints.put(P, i, p), _joints.put(G, i, _quat.mul(g_parent, _joints.get(local, i)))

    return _joints.loop(1, J, body, (P, G), unroll=unroll)


def joint_positions(parents, offsets, local):
    """``(J, 3)`` joint positions of stacked local rotations ``local (J, 4)`` (one pose).

    A chain goes through the rolled recursion (its derivatives compile several times
    faster), any other tree level by level (``stacked.fk_stacked``).
    """
    J = len(parents)
    if parents == chain_parents(J):
        return fk_joints(offsets, local, (), unroll=False)[0]
    return fk_stacked(parents, offsets, local)[0]


def fk(skeleton, rotations: jax.Array | None = None, *, unroll: bool | None = None) -> Pose:
    """Forward kinematics.

    Args:
      skeleton: a ``Skeleton`` (a chain is one) with ``offsets (J, 3)``.
      rotations: ``(..., J, 4)`` local rotations as quaternions (w, x, y, z); ``None`` is
        the rest pose.  Any leading batch shape is allowed.  They are normalised first
        (``q / |q|``, and a zero quaternion is the identity), so bone lengths are kept
        whatever the scale of ``q``.
      unroll: chains only: unroll the joint loop (default: ``J <= 16`` and a batch of
        >= 256): one tree level (joint) at a time; otherwise a ``fori_loop`` over
        joints.  Other trees go one tree level at a time.

    Returns:
      ``Pose`` with global ``positions (..., J, 3)`` and ``rotations (..., J, 4)``.
    """
    if rotations is None:
        rotations = skeleton.rest_rotations()
    return _fk(skeleton, array_like(rotations), unroll=unroll)


@functools.partial(jax.jit, static_argnames="unroll")
def _fk(skeleton, rotations, *, unroll):
    """:func:`fk` as one compiled program per skeleton shape (eagerly, a tree's FK would be
    hundreds of small dispatches, each compiled on its first shape)."""
    rotations = jnp.asarray(rotations, skeleton.offsets.dtype)
    J = skeleton.num_joints
    if rotations.shape[-2:] != (J, 4):
        raise ValueError(f"rotations must have shape (..., {J}, 4), got {rotations.shape}")
    rotations = _quat.unit_quaternions(rotations)
    batch = rotations.shape[:-2]
    if skeleton.is_chain and not _joints.unrolled(J, unroll, int(np.prod(batch))):
        P, G = fk_joints(skeleton.offsets, jnp.moveaxis(rotations, (-2, -1), (0, 1)), batch, unroll=False)
        return Pose(positions=jnp.moveaxis(P, (0, 1), (-2, -1)), rotations=jnp.moveaxis(G, (0, 1), (-2, -1)))
    P, G = fk_stacked(skeleton.parents, skeleton.offsets, rotations)
    return Pose(positions=P, rotations=G)
