"""Retargeting: a clip's end effectors drive another skeleton, by IK over the frames."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from .._dataclass import pytree_dataclass
from .._dtype import tiny
from .._validate import check_real
from .._geometry import quat as _quat
from .. import ik
from ._contacts import joint_ids
from ._motion import Motion, global_rotations, positions


@pytree_dataclass
class Retargeted:
    """The result of :func:`retarget`.

    Attributes:
      motion: the target skeleton's :class:`Motion`.
      error: ``(T, E)`` per frame and mapped effector, the distance (scene units) from the
        scaled source position.
      converged: ``(T,)`` bool, every effector within the solver's tolerance.
      scale: ``()`` target lengths per source length.
    """

    motion: Motion
    error: jax.Array
    converged: jax.Array
    scale: jax.Array


def _path_length(sk, j: int) -> jax.Array:
    """``()`` the summed bone lengths from the root to joint ``j`` (pose-independent;
    differentiable in the offsets)."""
    total = jnp.zeros((), sk.offsets.dtype)
    while j > 0:
        total = total + _quat.safe_norm(_quat.unstack(sk.offsets[j], -1))
        j = sk.parents[j]
    return total


def retarget(motion: Motion, skeleton, mapping: dict, *, scale=None, solver="lm", max_iters: int = 100,
             tol: float = 1e-4) -> Retargeted:
    """Drive ``skeleton`` with ``motion``'s joints named in ``mapping``.

    The root carries the source root's world rotation and its position times ``scale``;
    each mapped effector's target is the source joint's position relative to the source
    root, times ``scale``, and the rest of the pose is solved by ``ik.track`` (warm-started
    frame to frame) with the root held, so the target's joint limits are kept.  Both
    skeletons are taken to share their rest frame (y up, the character's left at +x, as
    the CMU rig and ``ik.humanoid`` do).

    Args:
      motion: the source clip.
      skeleton: the target ``ik.Skeleton`` (its ``offsets[0]`` is ignored: the root moves).
      mapping: ``{target joint: source joint}`` names (or indices), e.g. ``{"l_hand":
        "LeftWrist", "l_ankle": "LeftAnkle", ...}``.
      scale: target lengths per source length; default the leg-length ratio: the bone
        lengths summed from the root to the mapped joint lowest in the target's rest pose
        (an ankle), over the same for its source joint.
      solver, max_iters, tol: as in ``ik.track`` (default LM, which keeps limits).

    Returns:
      :class:`Retargeted`.
    """
    if not isinstance(skeleton, ik.Skeleton):
        raise TypeError(f"skeleton must be a jaxsim.ik.Skeleton, got {type(skeleton).__name__}")
    if not isinstance(mapping, dict) or not mapping:
        raise ValueError("mapping must be a non-empty dict {target joint: source joint}")
    src = joint_ids(motion.skeleton, tuple(mapping.values()), "mapping's source joints")
    tgt = list(joint_ids(skeleton, tuple(mapping), "mapping's target joints"))
    if 0 in tgt or 0 in src:
        raise ValueError("mapping must not name a root: the roots are mapped to each other")
    dtype = skeleton.offsets.dtype
    if scale is None:  # the legs: the mapped joint lowest in the target's rest pose, and its source
        low = jnp.argmin(ik.fk(skeleton).positions[jnp.asarray(tgt), 1])
        lengths = [jnp.stack([_path_length(sk, j) for j in ids]) for sk, ids in ((skeleton, tgt), (motion.skeleton, src))]
        scale = lengths[0][low] / jnp.maximum(lengths[1][low], tiny(dtype))
    if not isinstance(scale, jax.core.Tracer):
        check_real("scale", scale, minimum=0.0, strict=True)
    P = positions(motion)
    root_q = global_rotations(motion)[:, 0]
    rel = scale * (P[:, list(src)] - P[:, :1])  # (T, E, 3) in the world's axes, about the root
    inv = _quat.conj(_quat.unstack(root_q, -1))
    local = _quat.stack(_quat.rotate(tuple(c[:, None] for c in inv), _quat.unstack(rel, -1)), -1)
    limits = list(skeleton.limits or (None,) * skeleton.num_joints)
    limits[0] = ik.Fixed()
    held = dataclasses.replace(skeleton, offsets=skeleton.offsets.at[0].set(0.0), limits=tuple(limits))
    res = ik.track(held, local.astype(dtype), solver=solver, effectors=tuple(tgt), max_iters=max_iters, tol=tol)
    rot = res.rotations.at[:, 0].set(root_q.astype(dtype))
    channels = (("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),) + \
        (("Zrotation", "Xrotation", "Yrotation"),) * (skeleton.num_joints - 1)
    out = Motion(skeleton=skeleton, rotations=rot, root_positions=(scale * P[:, 0]).astype(dtype),
                 frame_time=motion.frame_time, channels=channels)
    return Retargeted(motion=out, error=res.error, converged=res.converged, scale=jnp.asarray(scale, dtype))
