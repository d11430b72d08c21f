"""The joint chain (a pytree dataclass), the lab's arm, and the FK output type."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._dataclass import is_concrete, pytree_dataclass
from .._dtype import as_float, check_array_dtype, tiny
from .._validate import check_finite


@pytree_dataclass
class Chain:
    """A serial chain of ``J`` ball joints.

    Attributes:
      offsets: ``(J, 3)``.  ``offsets[0]`` is the root joint's world position;
        ``offsets[i]`` for ``i >= 1`` is joint ``i``'s offset from joint ``i-1`` in the
        parent's frame (the lab's ``LocalOffset``), in scene units (metres in the lab).

    Raises:
      ValueError: on a wrong shape, ``J < 2``, non-finite values, a zero-length bone, a
        half-precision dtype, or a chain too large for its dtype (squared distances
        across it must not overflow: about 4e18 scene units in float32).
    """

    offsets: jax.Array

    def __post_init__(self):
        if not is_concrete(self.offsets):
            return  # rebuilt inside a transformation: leaves are tracers or placeholders
        a = np.asarray(self.offsets)
        if a.ndim != 2 or a.shape[-1] != 3:
            raise ValueError(f"Chain offsets must have shape (J, 3), got {a.shape}")
        if a.shape[0] < 2:
            raise ValueError(f"a Chain needs at least 2 joints (one bone), got J={a.shape[0]}")
        check_array_dtype("Chain", a.dtype)
        check_finite("Chain offsets", a)
        offsets = as_float(self.offsets)
        dtype = offsets.dtype
        lengths = np.linalg.norm(a[1:].astype(np.float64), axis=-1)
        if np.any(lengths <= tiny(dtype)):
            bad = np.flatnonzero(lengths <= tiny(dtype)) + 1
            raise ValueError(f"Chain has zero-length bones (shorter than {tiny(dtype):.1e} in {dtype}) at joint(s) "
                             f"{bad.tolist()}")
        span = float(np.abs(a[0].astype(np.float64)).max() + lengths.sum())
        limit = float(np.sqrt(np.finfo(dtype).max)) / 8
        if span >= limit:
            raise ValueError(f"Chain spans {span:.3g} scene units, too large for {dtype} (squared distances overflow "
                             f"beyond {limit:.2g}); use float64 or smaller units")
        object.__setattr__(self, "offsets", offsets)

    @property
    def num_joints(self) -> int:
        """``J``, the number of joints (a static Python int)."""
        return self.offsets.shape[-2]

    @property
    def root(self) -> jax.Array:
        """``(3,)`` world position of the root joint."""
        return self.offsets[..., 0, :]

    @property
    def lengths(self) -> jax.Array:
        """``(J-1,)`` bone lengths: ``lengths[i-1] = |offsets[i]|``."""
        o = self.offsets[..., 1:, :]
        return jnp.sqrt(jnp.sum(o * o, axis=-1))

    @property
    def reach(self) -> jax.Array:
        """Total length of the chain, the largest root-to-end distance."""
        return jnp.sum(self.lengths, axis=-1)

    def rest_rotations(self) -> jax.Array:
        """``(J, 4)`` identity local rotations, in the chain's dtype."""
        q = jnp.zeros(self.offsets.shape[:-1] + (4,), self.offsets.dtype)
        return q.at[..., 0].set(1.0)


@pytree_dataclass
class Pose:
    """Global joint frames from forward kinematics.

    Attributes:
      positions: ``(..., J, 3)`` world positions of the joints.
      rotations: ``(..., J, 4)`` world (global) rotations, unit quaternions (w, x, y, z).
    """

    positions: jax.Array
    rotations: jax.Array


def lab_arm() -> Chain:
    """The lab's 5-joint arm: root at (0, 1.7, 0), bones 0.8, 0.4, 0.2, 1.2 down -y (reach 2.6)."""
    return Chain(
        np.array(
            [[0.0, 1.7, 0.0], [0.0, -0.8, 0.0], [0.0, -0.4, 0.0], [0.0, -0.2, 0.0], [0.0, -1.2, 0.0]]
        )
    )


def straight_chain(lengths, root=(0.0, 0.0, 0.0), direction=(0.0, 0.0, 1.0)) -> Chain:
    """A chain whose bones of the given ``lengths`` all point along ``direction`` at rest."""
    lengths = np.asarray(lengths, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    if d.shape != (3,):
        raise ValueError(f"direction must be a 3-vector, got shape {d.shape}")
    n = np.linalg.norm(d)
    if not (np.isfinite(n) and n > 0):
        raise ValueError(f"direction must be a finite non-zero vector, got {direction!r}")
    if lengths.ndim != 1:
        raise ValueError(f"lengths must be a 1D sequence of bone lengths, got shape {lengths.shape}")
    d = d / n
    return Chain(np.concatenate([np.asarray(root, np.float64)[None], lengths[:, None] * d[None]]))
