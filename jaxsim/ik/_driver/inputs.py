"""Boundary checks for every IK entry point, before tracing, into one named record."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ..._dataclass import is_concrete
from ..._validate import check_bool, check_finite
from ..._geometry import quat as _quat
from .._solvers.settings import _Settings
from .._model.skeleton import Skeleton, check_effectors

#: Default orientation weight (scene units per radian): 1 degree of error weighs as ~1.7 mm.
ORIENTATION_WEIGHT = 0.1


@dataclasses.dataclass(frozen=True)
class Inputs:
    """A solve's checked inputs, in the skeleton's dtype.

    Attributes:
      effectors: static tuple of ``E`` joint ids.
      targets: ``(..., E, 3)``.
      rotations: ``(J, 4)`` (one start pose for the batch) or ``(..., J, 4)``, unit.
      weights: ``(E,)`` positive effector weights.
      orientations: ``(..., E, 4)`` unit quaternions, or ``None``.
      orientation_weights: ``(E,)``, or ``None`` without orientations.
      batch: the broadcast batch shape ``(...)``.
    """

    effectors: tuple
    targets: jax.Array
    rotations: jax.Array
    weights: jax.Array
    orientations: jax.Array | None
    orientation_weights: jax.Array | None
    batch: tuple


def check_model(model, settings=None):
    """``TypeError`` unless ``model`` is a ``Skeleton`` (and ``settings`` an IK settings object)."""
    if not isinstance(model, Skeleton):
        raise TypeError(f"the model must be a jaxsim.ik.Skeleton (jaxsim.ik.Chain builds one), got "
                        f"{type(model).__name__}")
    if settings is not None and not isinstance(settings, _Settings):
        raise TypeError(f"settings must be jaxsim.ik.FABRIK, CCD or LevenbergMarquardt, got {settings!r}")
    zero = model.zero_length_joints()
    if zero:
        names = f" ({', '.join(model.names[i] for i in zero)})" if model.names else ""
        raise ValueError(f"the IK solvers need bones of positive length; joint(s) {list(zero)}{names} have zero-length "
                         "offsets from their parents (FK and jaxsim.anim take them)")


def check_flags(optional=(), **flags):
    """Each keyword must be a bool; those named in ``optional`` may also be ``None`` (their default)."""
    for name, flag in flags.items():
        if not (flag is None and name in optional):
            check_bool(name, flag)


def check_start_rotations(rotations):
    """Start rotations must be finite and non-zero (checked when concrete, i.e. outside ``jit``)."""
    if is_concrete(rotations):
        r = check_finite("rotations", rotations)
        if np.any(np.linalg.norm(r, axis=-1) < 1e-6):
            raise ValueError("rotations contain a zero quaternion; use (1, 0, 0, 0) for no rotation")


def _orientations(dtype, orientations, orientation_weights, E):
    if orientations is None:
        if orientation_weights is not None:
            raise ValueError("orientation_weights needs orientations")
        return None, None
    o = jnp.asarray(orientations, dtype)
    if o.ndim == 1 and E == 1:
        o = o[None]
    if o.ndim < 2 or o.shape[-2:] != (E, 4):
        raise ValueError(f"orientations must have shape (..., {E}, 4), one unit quaternion per effector, got {o.shape}")
    if is_concrete(o):
        norms = np.linalg.norm(check_finite("orientations", o).astype(np.float64), axis=-1)
        off = np.abs(norms - 1.0) > 1e-4
        if np.any(off):
            raise ValueError(f"orientations must be unit quaternions; {int(np.sum(off))} have a norm off 1 by more "
                             f"than 1e-4 (worst {norms.flat[np.argmax(np.abs(norms - 1))]!r})")
    o = _quat.unit_quaternions(o)
    if orientation_weights is None:
        return o, jnp.full((E,), ORIENTATION_WEIGHT, dtype)
    ow = jnp.asarray(orientation_weights, dtype)
    if ow.shape != (E,):
        raise ValueError(f"orientation_weights must have shape ({E},), got {ow.shape}")
    if is_concrete(ow) and np.any(check_finite("orientation_weights", ow) < 0):
        raise ValueError("orientation_weights must be >= 0")
    return o, ow


def _targets_array(targets, dtype):
    """``targets`` as a real array of ``dtype``: ``ValueError`` naming them for a string or other
    non-numeric value, or complex numbers (whose imaginary part a cast would drop)."""
    if isinstance(targets, (jax.Array, jax.core.Tracer)):
        kind = targets.dtype
    else:
        try:
            kind = np.asarray(targets).dtype
        except (TypeError, ValueError) as e:
            raise ValueError(f"targets must be an array of numbers, got {targets!r}") from e
    if not (np.issubdtype(kind, np.floating) or np.issubdtype(kind, np.integer)):
        what = repr(targets) if isinstance(targets, str) else f"an array of {kind}"
        raise ValueError(f"targets must be real numbers, got {what}")
    return jnp.asarray(targets, dtype)


def check_inputs(skeleton: Skeleton, targets, rotations=None, effectors=None, weights=None, orientations=None,
                 orientation_weights=None) -> Inputs:
    """The checked :class:`Inputs` of a solve.

    ``targets`` are ``(..., E, 3)``.  With one effector the last axis is the target:
    ``(..., 3)`` is read as ``(..., 1, 3)``, so ``(3,)`` is one target and ``(N, 3)`` is
    ``N``; an array whose second-to-last axis is already 1 is taken as the general form
    (``(1, 3)`` is one target, with no batch axis).  A single ``(4,)`` orientation is read
    as ``(1, 4)``.

    Raises:
      ValueError: on a wrong shape, non-finite targets or start rotations, a zero
        quaternion, bad effectors, weights that are not positive, or orientations that
        are not unit quaternions.
    """
    dtype = skeleton.offsets.dtype
    effectors = check_effectors(skeleton, effectors)
    E, J = len(effectors), skeleton.num_joints
    targets = _targets_array(targets, dtype)
    if E == 1 and targets.ndim >= 1 and targets.shape[-1] == 3 and (targets.ndim == 1 or targets.shape[-2] != 1):
        targets = targets[..., None, :]  # one effector: the last axis is the target, (N, 3) is N targets
    if targets.ndim < 2 or targets.shape[-2:] != (E, 3):
        hint = (f"; an (N, 3) array is N targets for a one-effector model only: give ({targets.shape[0]}, {E}, 3), "
                "one target per effector" if E > 1 and targets.ndim == 2 and targets.shape[-1] == 3 else "")
        raise ValueError(f"targets must have shape (..., {E}, 3) for {E} effector(s) {effectors}, got "
                         f"{targets.shape}{hint}")
    if is_concrete(targets):
        check_finite("targets", targets)
    rotations = skeleton.rest_rotations() if rotations is None else jnp.asarray(rotations, dtype)
    if rotations.ndim < 2 or rotations.shape[-2:] != (J, 4):
        raise ValueError(f"rotations must have shape (..., {J}, 4) for this skeleton, got {rotations.shape}")
    check_start_rotations(rotations)
    if weights is None:
        weights = jnp.ones((E,), dtype)
    else:
        weights = jnp.asarray(weights, dtype)
        if weights.shape != (E,):
            raise ValueError(f"weights must have shape ({E},), one per effector, got {weights.shape}")
        if is_concrete(weights):
            wv = check_finite("weights", weights)
            if np.any(wv <= 0):
                raise ValueError(f"weights must be > 0, got min {wv.min()!r}")
    o, ow = _orientations(dtype, orientations, orientation_weights, E)
    batch = jnp.broadcast_shapes(targets.shape[:-2], rotations.shape[:-2], () if o is None else o.shape[:-2])
    return Inputs(effectors=effectors, targets=targets, rotations=_quat.unit_quaternions(rotations), weights=weights,
                  orientations=o, orientation_weights=ow, batch=tuple(batch))
