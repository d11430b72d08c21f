"""The public limit checks: how far rotations break a skeleton's limits, and their projection
onto them (``projection`` for one joint, ``stacked`` for all joints at once)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..._geometry import quat as _quat
from ..._validate import array_like
from .limits import limit_table
from .projection import violation
from .stacked import project_stacked


def _joint_rotations(skeleton, rotations):
    """``rotations (..., J, 4)`` checked and normalised: ``(bad (..., J), list of J tuples)``,
    ``bad`` marking rotations with a NaN or inf entry."""
    raw = jnp.asarray(rotations, skeleton.offsets.dtype)
    J = skeleton.num_joints
    if raw.shape[-2:] != (J, 4):
        raise ValueError(f"rotations must have shape (..., {J}, 4), got {raw.shape}")
    q = _quat.unit_quaternions(raw)
    return ~jnp.all(jnp.isfinite(raw), axis=-1), [_quat.unstack(q[..., i, :], axis=-1) for i in range(J)]


@jax.jit
def _limit_violation(skeleton, rotations):
    bad, L = _joint_rotations(skeleton, rotations)
    table = limit_table(skeleton)
    if table is None:
        v = jnp.zeros(bad.shape, L[0][0].dtype)
    else:
        v = jnp.stack([violation(q, table.joint(i)) for i, q in enumerate(L)], axis=-1)
    return jnp.where(bad, jnp.inf, v)


@jax.jit
def _project_limits(skeleton, rotations):
    bad, L = _joint_rotations(skeleton, rotations)
    L = project_stacked(limit_table(skeleton), jnp.stack([_quat.stack(q, axis=-1) for q in L], axis=-2))
    return jnp.where(bad[..., None], jnp.nan, L)


def limit_violation(skeleton, rotations) -> jax.Array:
    """Per joint, the angle (rad) by which ``rotations (..., J, 4)`` break the skeleton's limits.

    Returns:
      ``(..., J)``: 0 for a joint within its limit (and for a free joint); ``inf`` for a
      rotation with a NaN or inf entry, which is within no limit.
    """
    return _limit_violation(skeleton, array_like(rotations))


def project_limits(skeleton, rotations) -> jax.Array:
    """``rotations (..., J, 4)`` moved into the skeleton's limits, joint by joint (normalised first).

    A rotation already within its limit is returned unchanged (up to rounding); one with
    a NaN or inf entry comes back as NaN (it has no nearest rotation in the limit).
    """
    return _project_limits(skeleton, array_like(rotations))
