"""Two-bone IK in closed form: a limb (root, middle joint, end) bent toward a pole point.

The end goes on the line from the root to the target, at the distance the two bones can
span; the middle joint's bend (the angle between the bones, 0 straight) follows from
the law of cosines and is clamped to the hinge range; the middle joint lies in the
plane through the root, the target and the pole, on the pole's side.  The classic
analytic limb solver of animation rigs (elbows and knees).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from ..._dataclass import is_concrete, pytree_dataclass
from ..._geometry import quat as _quat
from ..._validate import check_finite
from .._model.projection import safe_atan2


@pytree_dataclass
class TwoBone:
    """A two-bone limb's solution (any leading batch shape ``...``).

    Attributes:
      mid: ``(..., 3)`` the middle joint's position.
      end: ``(..., 3)`` the end joint's position (on the target when ``reached``).
      bend: ``(...)`` the middle joint's bend (rad): the angle between the two bones, 0
        straight, within the given range.
      reached: ``(...)`` bool, the target within the distances the range allows.
    """

    mid: jax.Array
    end: jax.Array
    bend: jax.Array
    reached: jax.Array


def _check(root, target, pole, lengths, bend):
    lengths = np.asarray(lengths, dtype=np.float64) if is_concrete(lengths) else lengths
    if is_concrete(lengths):
        if np.shape(lengths) != (2,) or not np.all(np.isfinite(lengths)) or np.any(lengths <= 0):
            raise ValueError(f"lengths must be two positive bone lengths, got {lengths!r}")
    try:
        lo, hi = (float(b) for b in bend)
    except (TypeError, ValueError):
        raise ValueError(f"bend must be a (lo, hi) pair of angles in [0, pi], got {bend!r}") from None
    if not (0.0 <= lo <= hi <= math.pi + 1e-12):
        raise ValueError(f"bend must satisfy 0 <= lo <= hi <= pi (rad), got {bend!r}")
    for name, x in (("root", root), ("target", target), ("pole", pole)):
        if np.shape(x)[-1:] != (3,):
            raise ValueError(f"{name} must have shape (..., 3), got {np.shape(x)}")
        if is_concrete(x):
            check_finite(name, x)
    return lo, hi


def two_bone(root, target, pole, lengths, bend=(0.0, math.pi)) -> TwoBone:
    """Closed-form IK of a two-bone limb.

    Args:
      root: ``(..., 3)`` the limb's root joint (shoulder, hip).
      target: ``(..., 3)`` where the end joint (wrist, ankle) should go.
      pole: ``(..., 3)`` a point the middle joint (elbow, knee) bends toward.
      lengths: ``(2,)`` the two bone lengths, positive.
      bend: ``(lo, hi)`` the middle joint's range of bend, ``0 <= lo <= hi <= pi`` (rad;
        0 is the straight limb).

    Returns:
      :class:`TwoBone`.  A target beyond reach gets the limb at its largest span toward
      it, one too close the limb at its smallest; a target on the root gets the end on
      the root's side toward the pole (any direction if the pole is on the root too).
      The gradients are NaN-free, at the straight limb and on the root included.

    Raises:
      ValueError: lengths not two positive numbers, a bend range outside ``[0, pi]`` or
        with ``lo > hi``, a point not of shape ``(..., 3)``, or (outside ``jit``) a NaN
        or infinite point.
    """
    lo, hi = _check(root, target, pole, lengths, bend)
    root, target, pole = jnp.broadcast_arrays(*(jnp.asarray(x) for x in (root, target, pole)))
    dtype = jnp.result_type(root, target, pole, 0.0)  # the points' float type; integers: the default float
    return _two_bone(root.astype(dtype), target.astype(dtype), pole.astype(dtype), jnp.asarray(lengths, dtype),
                     jnp.asarray(lo, dtype), jnp.asarray(hi, dtype))


@jax.jit
def _two_bone(root, target, pole, lengths, lo, hi) -> TwoBone:
    """:func:`two_bone` on checked arrays of one float dtype (one compiled program per shape)."""
    l1, l2 = lengths[0], lengths[1]
    a, t, p = (_quat.unstack(x, axis=-1) for x in (root, target, pole))
    v = _quat.sub(t, a)
    dist = _quat.safe_norm(v)
    side = _quat.sub(p, a)
    u = _quat.normalize(v, _quat.normalize(side, _quat.perpendicular(v)))
    span = [jnp.sqrt(l1 * l1 + l2 * l2 + 2 * l1 * l2 * jnp.cos(x)) for x in (hi, lo)]  # smallest, largest
    d = jnp.clip(dist, span[0], span[1])
    # the bend from the law of cosines, by atan2 of (sin, cos) of it: NaN-free where straight
    c = jnp.clip((d * d - l1 * l1 - l2 * l2) / (2 * l1 * l2), -1.0, 1.0)
    theta = jnp.clip(safe_atan2(_quat.safe_sqrt(jnp.maximum(1.0 - c * c, 0.0)), c), lo, hi)
    alpha = safe_atan2(l2 * jnp.sin(theta), l1 + l2 * jnp.cos(theta))  # root -> mid against root -> end
    across = _quat.sub(side, _quat.scale(_quat.dot(side, u), u))
    n = _quat.normalize(across, _quat.perpendicular(u))
    mid = _quat.add(a, _quat.scale(l1, _quat.add(_quat.scale(jnp.cos(alpha), u), _quat.scale(jnp.sin(alpha), n))))
    end = _quat.add(a, _quat.scale(d, u))
    return TwoBone(mid=_quat.stack(mid, axis=-1), end=_quat.stack(end, axis=-1), bend=theta,
                   reached=(dist >= span[0]) & (dist <= span[1]))
