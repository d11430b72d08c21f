"""A clip: a skeleton and its local rotations and root positions over frames."""

from __future__ import annotations

import functools

import jax
import numpy as np

from .._dataclass import is_concrete, pytree_dataclass, static_field
from .._dtype import as_float, check_array_dtype
from .._validate import check_real
from .._geometry import quat as _quat
from ..ik import Skeleton
from ..ik._model.stacked import fk_stacked


@pytree_dataclass
class Motion:
    """``T`` frames of a ``J``-joint skeleton, as read from a BVH file.

    Attributes:
      skeleton: ``ik.Skeleton`` with the file's joint names, in file order; ``offsets[0]``
        is the root's ``OFFSET``, ``offsets[i]`` joint ``i``'s ``OFFSET`` (scene units,
        the file's times ``scale``).
      rotations: ``(T, J, 4)`` local rotations (w, x, y, z); identity for a joint without
        rotation channels.
      root_positions: ``(T, 3)`` the root's world position per frame (its ``OFFSET`` plus
        its position channels).
      translations: ``(T, J, 3)`` per-frame translations added to the offsets, when a
        joint other than the root has position channels (their values; zero elsewhere and
        on the root's row), else ``None``.
      frame_time: static, seconds per frame.
      channels: static, per joint the tuple of its channel names in file order
        (``"Xposition"``, ..., ``"Zrotation"``).
      end_sites: static, per ``End Site`` a ``(joint, (x, y, z))`` pair: the joint it
        hangs from and its offset in that joint's frame (scene units).
    """

    skeleton: Skeleton
    rotations: jax.Array
    root_positions: jax.Array
    translations: jax.Array | None = None
    frame_time: float = static_field(default=1 / 30)
    channels: tuple = static_field(default=())
    end_sites: tuple = static_field(default=())

    def __post_init__(self):
        if not isinstance(self.skeleton, Skeleton):
            raise TypeError(f"skeleton must be a jaxsim.ik.Skeleton, got {type(self.skeleton).__name__}")
        if not is_concrete(self.rotations, self.root_positions):
            return  # rebuilt inside a transformation
        J = self.skeleton.num_joints
        r, p = np.shape(self.rotations), np.shape(self.root_positions)
        if len(r) != 3 or r[1:] != (J, 4):
            raise ValueError(f"rotations must have shape (T, {J}, 4) for {J} joints, got {r}")
        if p != (r[0], 3):
            raise ValueError(f"root_positions must have shape ({r[0]}, 3) for {r[0]} frames, got {p}")
        if self.translations is not None and np.shape(self.translations) != (r[0], J, 3):
            raise ValueError(f"translations must have shape ({r[0]}, {J}, 3) or be None, got {np.shape(self.translations)}")
        dtype = self.skeleton.offsets.dtype  # array-likes become the skeleton's float dtype
        for name in ("rotations", "root_positions", "translations"):
            value = getattr(self, name)
            if value is None:
                continue
            a = np.asarray(value)
            check_array_dtype(f"Motion {name}", a.dtype)
            bad = ~np.isfinite(a).all(axis=tuple(range(1, a.ndim)))
            if bad.any():
                raise ValueError(f"Motion {name} must be finite; not in frames {np.flatnonzero(bad)[:5].tolist()}")
            object.__setattr__(self, name, as_float(value, dtype))
        object.__setattr__(self, "frame_time", check_real("frame_time (seconds)", self.frame_time, minimum=0.0,
                                                          strict=True))
        if r[0] < 1:
            raise ValueError("a Motion needs at least 1 frame, got rotations of shape " + str(r))
        norms = np.linalg.norm(np.asarray(self.rotations, np.float64), axis=-1)
        if np.any(norms < 1e-6):
            t, j = np.argwhere(norms < 1e-6)[0]
            raise ValueError(f"Motion rotations hold a zero quaternion (frame {t}, joint {j}), which is no rotation; "
                             "use (1, 0, 0, 0) for none")
        if self.channels:
            _check_channels(self.channels, J)
        for k, site in enumerate(self.end_sites):
            if not (isinstance(site, tuple) and len(site) == 2 and isinstance(site[0], (int, np.integer))
                    and 0 <= site[0] < J and np.shape(site[1]) == (3,)):
                raise ValueError(f"end_sites[{k}] must be (joint id in [0, {J}), (x, y, z)), got {site!r}")

    @property
    def num_frames(self) -> int:
        """``T`` (a static Python int)."""
        return self.rotations.shape[0]

    def rotation_order(self, joint: int) -> str:
        """The joint's rotation axes in composition order, e.g. ``"ZXY"`` (``""`` if none)."""
        return "".join(c[0] for c in self.channels[joint] if c.endswith("rotation"))


#: The six BVH channel names.
CHANNELS = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")


def _check_channels(channels, J: int) -> None:
    """Per joint a tuple of distinct names from :data:`CHANNELS` (any subset, any order)."""
    if len(channels) != J:
        raise ValueError(f"channels must name each of the {J} joints' channels, got {len(channels)} entries")
    for i, own in enumerate(channels):
        bad = [c for c in own if c not in CHANNELS]
        if bad:
            raise ValueError(f"channels[{i}] holds {bad[0]!r}, not a channel name (one of {', '.join(CHANNELS)})")
        if len(set(own)) != len(own):
            raise ValueError(f"channels[{i}] lists a channel twice: {own}")


def _offsets(motion: Motion) -> jax.Array:
    """``(J, 3)`` the skeleton's offsets, or ``(T, J, 3)`` with the translations added."""
    off = motion.skeleton.offsets
    return off if motion.translations is None else off + motion.translations


@functools.partial(jax.jit, static_argnames=("parents",))
def _fk(parents, offsets, root, rotations):
    """``(P (T, J, 3), G (T, J, 4))`` of ``offsets (J, 3)`` or ``(T, J, 3)`` and the root's
    world positions ``root (T, 3)``: FK about the root, then the root added (its rotation
    turns only its children's offsets)."""
    P, G = fk_stacked(parents, offsets.at[..., 0, :].set(0.0), _quat.unit_quaternions(rotations))
    return P + root[:, None], G


def positions(motion: Motion) -> jax.Array:
    """``(T, J, 3)`` world positions of every joint over the clip: one jitted FK, batched
    over frames, one tree level at a time (``ik._model.stacked.fk_stacked``).  Differentiable in
    the offsets, rotations and root positions."""
    return _fk(motion.skeleton.parents, _offsets(motion), motion.root_positions, motion.rotations)[0]


def global_rotations(motion: Motion) -> jax.Array:
    """``(T, J, 4)`` world rotations of every joint over the clip."""
    return _fk(motion.skeleton.parents, _offsets(motion), motion.root_positions, motion.rotations)[1]
