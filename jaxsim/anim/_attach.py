"""What a clip drives: its frames at another rate, points fixed to bones, and body capsules."""

from __future__ import annotations

import numpy as np
import jax
import jax.numpy as jnp

from .._dataclass import is_concrete
from .._geometry import quat as _quat
from .._validate import check_finite, check_real, check_shape
from ._motion import Motion, _fk, _offsets


#: The most frames :func:`resample` makes (10 minutes at 1 kHz).
MAX_FRAMES = 600_000


def resample(motion: Motion, frame_time: float, start: float = 0.0, duration: float | None = None) -> Motion:
    """The clip at another frame rate: slerp for the rotations, linear for the root and the
    translations.

    Args:
      motion: the clip.
      frame_time: seconds per frame of the result (e.g. the cloth's ``dt``), > 0.
      start: the clip's time of the result's first frame (s), in ``[0, length]``.
      duration: seconds to cover (default: to the clip's end); the result has
        ``floor(duration / frame_time) + 1`` frames, the last at or before the clip's end.

    Returns:
      a :class:`Motion` with ``frame_time``, the same skeleton, channels and end sites.
      Differentiable in the clip's rotations, root positions and translations.
    """
    if not isinstance(motion, Motion):
        raise TypeError(f"motion must be a jaxsim.anim.Motion, got {type(motion).__name__}")
    dt = check_real("frame_time", frame_time, minimum=0.0, strict=True)
    T, ft = motion.num_frames, motion.frame_time
    length = (T - 1) * ft
    start = check_real("start", start, minimum=0.0)
    if start > length * (1 + 1e-9):
        raise ValueError(f"start must lie within the clip's {length:.4g} s, got {start!r}")
    left = length - start
    if duration is not None:
        duration = check_real("duration", duration, minimum=0.0)
        if duration > left * (1 + 1e-9) + 1e-12:
            raise ValueError(f"duration {duration!r} s runs past the clip's end ({left:.4g} s after start={start!r})")
        left = duration
    K = int(np.floor(left / dt * (1 + 1e-9) + 1e-9)) + 1
    if K > MAX_FRAMES:
        raise ValueError(f"frame_time={frame_time!r} s over {left:.4g} s makes {K:,} frames (at most {MAX_FRAMES:,}): "
                         "a frame time this small is likely a unit slip (seconds per frame)")
    s = np.clip((start + dt * np.arange(K)) / ft, 0.0, T - 1)
    i = np.minimum(np.floor(s).astype(np.int64), max(T - 2, 0))
    f = jnp.asarray(s - i, motion.rotations.dtype)
    j = np.minimum(i + 1, T - 1)
    rot, root, trans = _interpolated(motion.rotations, motion.root_positions, motion.translations, jnp.asarray(i),
                                     jnp.asarray(j), f)
    return Motion(motion.skeleton, rot, root, trans, frame_time=dt, channels=motion.channels,
                  end_sites=motion.end_sites)


@jax.jit
def _interpolated(rotations, root, translations, i, j, f):
    """Frames ``i + f`` of a clip: rotations by slerp, positions by lerp (``i, j, f (K,)``)."""
    def lerp(a):
        return a[i] + f.reshape(f.shape + (1,) * (a.ndim - 1)) * (a[j] - a[i])

    q0, q1 = _quat.unstack(rotations[i], axis=-1), _quat.unstack(rotations[j], axis=-1)
    rot = _quat.stack(_quat.slerp(q0, q1, f[:, None]), axis=-1)
    return rot, lerp(root), None if translations is None else lerp(translations)


def _joint(motion: Motion, joint) -> int:
    """A joint id from a name or an id, checked."""
    J = motion.skeleton.num_joints
    if isinstance(joint, str):
        return motion.skeleton.index(joint)
    if isinstance(joint, (bool, np.bool_)) or not isinstance(joint, (int, np.integer)) or not 0 <= joint < J:
        raise ValueError(f"joint must be a joint name or an id in [0, {J}), got {joint!r}")
    return int(joint)


def _frames(motion: Motion, frame_time):
    """``(P (T, J, 3), G (T, J, 4))`` of the clip, resampled to ``frame_time`` when given."""
    if frame_time is not None:
        motion = resample(motion, frame_time)
    return _fk(motion.skeleton.parents, _offsets(motion), motion.root_positions, motion.rotations)


def bone_points(motion: Motion, joint, local_points, frame_time: float | None = None):
    """``(T, K, 3)`` world positions over the clip of points fixed in a joint's frame.

    For pin paths (``cloth.rollout(..., pins=)``): a cape's top edge fixed to the chest.
    The joint's frame is the one its children's offsets are given in: origin at the joint,
    turned by its world rotation.

    Args:
      motion: the clip.
      joint: the joint's name or id.
      local_points: ``(K, 3)`` the points in the joint's frame (scene units).
      frame_time: resample the clip to this many seconds per frame first (:func:`resample`),
        or ``None`` to keep its frames.

    Differentiable in the clip and in ``local_points``.
    """
    j = _joint(motion, joint)
    if is_concrete(local_points):
        check_finite("local_points", check_shape("local_points", local_points, (None, 3)))
    local = jnp.asarray(local_points, motion.skeleton.offsets.dtype)
    if local.ndim != 2 or local.shape[1] != 3:
        raise ValueError(f"local_points must have shape (K, 3), got {tuple(local.shape)}")
    P, G = _frames(motion, frame_time)
    return _carried(P[:, j], G[:, j], local)


@jax.jit
def _carried(p, g, local):
    """``(T, K, 3)``: the points ``local (K, 3)`` carried by a joint's frames, origin ``p (T, 3)``,
    rotation ``g (T, 4)``."""
    q = _quat.unstack(g[:, None, :], axis=-1)
    v = _quat.unstack(local[None], axis=-1)
    return p[:, None, :] + _quat.stack(_quat.rotate(q, v), axis=-1)


def bone_local(motion: Motion, joint, points, frame: int = 0):
    """``(K, 3)`` world ``points (K, 3)`` in a joint's frame at ``frame``: the inverse of
    :func:`bone_points` there, so ``bone_points(motion, joint, bone_local(motion, joint, x))``
    starts at ``x`` (a cape's top edge where it hangs at the clip's first frame)."""
    j = _joint(motion, joint)
    T = motion.num_frames
    if isinstance(frame, (bool, np.bool_)) or not isinstance(frame, (int, np.integer)) or not -T <= frame < T:
        raise ValueError(f"frame must be a frame index in [{-T}, {T}), got {frame!r}")
    if is_concrete(points):
        check_finite("points", check_shape("points", points, (None, 3)))
    x = jnp.asarray(points, motion.skeleton.offsets.dtype)
    P, G = _frames(motion, None)
    q = _quat.unstack(jnp.broadcast_to(G[frame, j], (x.shape[0], 4)), axis=-1)
    return _quat.stack(_quat.rotate(_quat.conj(q), _quat.unstack(x - P[frame, j], axis=-1)), axis=-1)


def _bone(motion: Motion, key) -> tuple[int, int]:
    """``(from, to)`` joint ids of a bone: a pair, or a joint with one child."""
    if isinstance(key, tuple):
        if len(key) != 2:
            raise ValueError(f"a bone is a joint or a (from, to) pair of joints, got {key!r}")
        return _joint(motion, key[0]), _joint(motion, key[1])
    j = _joint(motion, key)
    kids = motion.skeleton.children[j]
    if len(kids) != 1:
        names = motion.skeleton.names
        label = names[j] if names else j
        raise ValueError(f"joint {label!r} has {len(kids)} children; name its bone as a (from, to) pair of joints")
    return j, kids[0]


def body_capsules(motion: Motion, radii: dict, frame_time: float | None = None, friction: float = 0.0):
    """Capsules along a clip's bones, as a collider path for ``cloth.rollout(colliders=)``.

    Args:
      motion: the clip.
      radii: ``{bone: radius}``; a bone is a joint with one child (the segment from it to
        the child: ``"LeftShoulder"`` is the upper arm of ``cmu_walk``) or a ``(from, to)``
        pair of joints (names or ids); radius in scene units, > 0.
      frame_time: resample the clip first (:func:`resample`), or ``None``.
      friction: Coulomb coefficient of every capsule.

    Returns:
      a tuple of ``cloth.Capsule`` whose leaves have a leading ``(T,)`` axis, in the
      order of ``radii``.  Frame 0 is the scene's colliders
      (``jax.tree.map(lambda a: a[0], caps)``) and frames ``1..T-1`` the path of a
      ``T - 1``-step rollout (``jax.tree.map(lambda a: a[1:], caps)``).
    """
    from ..cloth import Capsule  # anim does not need cloth otherwise

    if not isinstance(radii, dict) or not radii:
        raise ValueError(f"radii must be a non-empty dict {{bone: radius}}, got {radii!r:.100}")
    friction = check_real("friction", friction, minimum=0.0)
    P, _ = _frames(motion, frame_time)
    T = P.shape[0]
    out = []
    for key, r in radii.items():
        a, b = _bone(motion, key)
        r = check_real(f"radius of bone {key!r}", r, minimum=0.0, strict=True)
        out.append(Capsule(P[:, a], P[:, b], jnp.full((T,), r, P.dtype), jnp.full((T,), friction, P.dtype),
                           frictional=friction > 0))
    return tuple(out)
