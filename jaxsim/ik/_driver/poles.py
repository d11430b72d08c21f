"""Pole targets: the limb each pole bends, and the checked pole points.

``solve(..., poles={joint: point})`` names a limb by its middle joint ``m`` (an elbow, a
knee): the limb runs from ``m``'s parent (the shoulder, the hip) through ``m`` to the one
effector below it (the hand, the ankle: ``m``'s child or grandchild), and the pole point
says on which side of the line from the limb's root to its end the middle joint bends
(``residual.pole_rows``; the classic rig control, as :func:`jaxsim.ik.two_bone`).
"""

from __future__ import annotations

from collections.abc import Mapping

import jax.numpy as jnp
import numpy as np

from ..._dataclass import is_concrete
from ..._validate import check_finite
from .._model.fk import fk
from .._model.skeleton import Skeleton, check_effectors, steps_below


def check_poles(skeleton: Skeleton, poles, effectors: tuple, batch: tuple):
    """``(limbs, points)``: static ``(root, middle, end)`` triples and ``points (*batch, K, 3)``
    in the skeleton's dtype, or ``((), None)`` without poles.

    Raises:
      ValueError: ``poles`` not a mapping of joints to points; a joint that is not the middle
        of a limb (the root, one without exactly one effector below it, or one whose
        effector is more than two joints below); a joint given
        twice; a point not of shape ``(..., 3)`` or not broadcastable to the batch; a NaN or
        infinite point (outside ``jit``); a point on the limb's root at rest.
    """
    if poles is None:
        return (), None
    if not isinstance(poles, Mapping):
        raise ValueError(f"poles must be a dict {{joint: point (..., 3)}}, got {type(poles).__name__}")
    if not poles:
        return (), None
    dtype, parents = skeleton.offsets.dtype, skeleton.parents
    rest = None
    limbs, points = [], []
    for key, point in poles.items():
        try:
            (m,) = check_effectors(skeleton, (key,))
        except ValueError as err:
            raise ValueError(f"pole joint {key!r}: {err}") from None
        if parents[m] < 0:
            raise ValueError(f"pole on joint {key!r}: the root is no limb's middle joint")
        below = [e for e in effectors if (steps_below(parents, e, m) or 0) > 0]
        if len(below) != 1:
            raise ValueError(f"pole on joint {key!r}: a pole's joint is the middle of a limb with one effector below "
                             f"it, and {len(below)} of the effectors {effectors} are below it")
        steps = steps_below(parents, below[0], m)
        if steps > 2:
            raise ValueError(f"pole on joint {key!r}: not the middle of a two-bone limb (its effector, joint {below[0]}, "
                             f"is {steps} joints below it; a limb's end is the middle joint's child or grandchild)")
        if any(t[1] == m for t in limbs):
            raise ValueError(f"pole on joint {key!r} given twice")
        p = jnp.asarray(point, dtype)
        if p.ndim < 1 or p.shape[-1] != 3:
            raise ValueError(f"pole on joint {key!r} must have shape (..., 3), got {p.shape}")
        try:
            fits = np.broadcast_shapes(p.shape[:-1], batch) == tuple(batch)
        except ValueError:
            fits = False
        if not fits:
            raise ValueError(f"pole on joint {key!r} has batch shape {p.shape[:-1]}, not broadcastable to the "
                             f"targets' {tuple(batch)}")
        if is_concrete(p):
            check_finite(f"pole on joint {key!r}", p)
            if rest is None:
                rest = np.asarray(fk(skeleton).positions, np.float64)
            gap = np.linalg.norm(np.asarray(p, np.float64) - rest[parents[m]], axis=-1)
            if np.any(gap <= 1e-9 * max(1.0, float(np.abs(rest).max()))):
                raise ValueError(f"pole on joint {key!r} lies on the limb's root (joint {parents[m]}) at rest, which "
                                 "gives the bend no side")
        limbs.append((parents[m], m, below[0]))
        points.append(jnp.broadcast_to(p, tuple(batch) + (3,)))
    return tuple(limbs), jnp.stack(points, axis=-2)

