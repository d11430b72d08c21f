"""Tracking a target trajectory frame by frame, warm-started, with optional jitter control."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._dataclass import is_concrete
from .._validate import check_finite, check_real
from . import _joints, _quat
from ._chain import Chain
from ._fk import fk_joints
from ._result import IKResult
from ._solve import _check_target_and_rotations, _run, check_settings


def rotation_change(a, b):
    """Angle in radians of the rotation taking ``a`` to ``b``: ``angle(a^{-1} b)``.

    Args:
      a, b: ``(..., 4)`` unit quaternions.

    Returns:
      ``(...)`` angles in ``[0, pi]``.
    """
    qa, qb = _quat.unstack(jnp.asarray(a), axis=-1), _quat.unstack(jnp.asarray(b), axis=-1)
    return _quat.angle(_quat.mul(_quat.conj(qa), qb))


def jitter(rotations, start=None):
    """Per-frame jitter: the largest joint rotation change between consecutive frames.

    Args:
      rotations: ``(T, J, 4)`` local rotations, one pose per frame.
      start: ``(J, 4)`` pose before frame 0 (default: frame 0 itself, giving 0 there).

    Returns:
      ``(T,)`` radians; ``jitter[t] = max_j angle(L_{t-1,j}^{-1} L_{t,j})``.
    """
    rotations = jnp.asarray(rotations)
    if rotations.ndim != 3 or rotations.shape[-1] != 4:
        raise ValueError(f"jitter needs rotations of shape (T, J, 4), one pose per frame, got {rotations.shape}")
    prev0 = rotations[:1] if start is None else jnp.asarray(start, rotations.dtype)[None]
    prev = jnp.concatenate([prev0, rotations[:-1]], axis=0)
    return jnp.max(rotation_change(prev, rotations), axis=-1)


@functools.partial(jax.jit, static_argnames=("kind", "max_iters", "unroll", "clamp"))
def _track(offsets, targets, local0, tol, max_step, *, kind, max_iters, unroll, clamp):
    J = local0.shape[0]

    def pose(local):
        P, _ = fk_joints(offsets, _joints.split(local, unroll), (), unroll=unroll)
        return _joints.stack(P)

    def frame(prev, target):
        local_prev, P_prev = prev
        local, P, err, iters, conv, reachable, errs = _run(
            offsets, target, local_prev, tol, kind=kind, max_iters=max_iters, unroll=unroll, trace=True
        )
        if clamp:
            a, b = _quat.unstack(local_prev, axis=1), _quat.unstack(local, axis=1)  # tuples of (J,)
            delta = _quat.clamp_angle(_quat.mul(_quat.conj(a), b), max_step)
            local = _quat.stack(_quat.renormalize(_quat.mul(a, delta)), axis=1)
            P = pose(local)
            err = _quat.safe_norm(_quat.sub(_quat.unstack(P[J - 1]), _quat.unstack(target)))
            conv = err <= tol
        # a non-finite target (only possible under jit) must not poison later frames:
        # keep the last good pose and flag the frame (error inf, not converged)
        good = jnp.all(jnp.isfinite(target)) & jnp.all(jnp.isfinite(local)) & jnp.all(jnp.isfinite(P))
        local, P = jnp.where(good, local, local_prev), jnp.where(good, P, P_prev)
        inf = jnp.array(jnp.inf, err.dtype)
        out = (local, P, jnp.where(good, err, inf), jnp.where(good, iters, 0), conv & good, reachable & good,
               jnp.where(good, errs, inf))
        return (local, P), out

    _, out = lax.scan(frame, (local0, pose(local0)), targets)
    return out


def track(chain: Chain, targets, *, solver: str = "fabrik", rotations=None, max_iters: int = 100,
          tol=1e-4, max_step_angle=None, unroll: bool | None = None) -> IKResult:
    """Follow a trajectory of targets, warm-starting each frame from the previous solution.

    One ``lax.scan`` over frames, as the lab's viewer does frame by frame.

    Args:
      chain: the chain, ``offsets (J, 3)``.
      targets: ``(T, 3)`` one target per frame.
      solver: ``"fabrik"`` or ``"ccd"``.
      rotations: ``(J, 4)`` pose before frame 0; ``None`` = rest pose.
      max_iters, tol: per-frame solver settings, as in :func:`jaxsim.ik.ccd`.
      max_step_angle: if given (radians), each joint's local rotation may change by at
        most this much per frame; the solution is pulled back along the same rotation
        axis.  This is the lab's answer to frame-to-frame jitter; the price is tracking
        error while the bound is active (reported in ``error``/``converged``).
      unroll: unroll the joint loop (default: rolled, the faster choice for one target).

    Returns:
      ``IKResult`` whose fields have a leading ``T`` axis; ``trace`` is ``(T, max_iters)``.
      Under ``jit`` a non-finite target cannot raise: that frame keeps the previous
      pose and reports ``error = inf``, ``iterations = 0``, ``converged = False``, and
      later frames go on from the last good pose.
    """
    check_settings(chain, solver, max_iters, tol)
    dtype = chain.offsets.dtype
    targets = jnp.asarray(targets, dtype)
    J = chain.num_joints
    if targets.ndim != 2 or targets.shape[-1] != 3:
        raise ValueError(f"targets must have shape (T, 3), got {targets.shape}")
    if is_concrete(targets):
        check_finite("targets", targets)
    rotations = chain.rest_rotations() if rotations is None else jnp.asarray(rotations, dtype)
    if rotations.shape != (J, 4):
        raise ValueError(f"rotations must have shape ({J}, 4), got {rotations.shape}")
    _check_target_and_rotations(chain, targets, rotations)
    rotations = _quat.unit_quaternions(rotations)
    if max_step_angle is not None and is_concrete(max_step_angle):
        check_real("max_step_angle", max_step_angle, minimum=0.0, strict=True)
    local, P, err, iters, conv, reachable, errs = _track(
        chain.offsets,
        targets,
        rotations,
        jnp.asarray(tol, dtype),
        jnp.asarray(np.pi if max_step_angle is None else max_step_angle, dtype),
        kind=solver,
        max_iters=int(max_iters),
        unroll=_joints.unrolled(J, unroll, 1),
        clamp=max_step_angle is not None,
    )
    return IKResult(rotations=local, positions=P, error=err, iterations=iters, converged=conv,
                    reachable=reachable, trace=errs)
