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
from ._lm import lm_one
from ._settings import resolve_settings
from ._limits import limit_table, project_all
from ._skeleton import Skeleton, topology
from ._solve import _check_target_and_rotations, _run, check_settings
from ._tree_fk import fk_tree
from ._tree_solve import check_tree_inputs, run_tree


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


def _project_rows(table, local):
    """``(J, 4)`` rotations projected onto the limits."""
    return _quat.stack([_quat.stack(q) for q in project_all(table, [_quat.unstack(local[i]) for i in range(len(local))])])


def _frame(res, prev, target, tol, max_step, *, clamp, pose, errors, limit=None):
    """One tracked frame after its solve: clamp the change per joint, and keep the last
    good pose if the frame is not finite (under jit a non-finite target cannot raise)."""
    local_prev, P_prev = prev
    local, P, err, iters, conv = res.rotations, res.positions, res.error, res.iterations, res.converged
    if clamp:
        a, b = _quat.unstack(local_prev, axis=1), _quat.unstack(local, axis=1)  # tuples of (J,)
        delta = _quat.clamp_angle(_quat.mul(_quat.conj(a), b), max_step)
        local = _quat.stack(_quat.renormalize(_quat.mul(a, delta)), axis=1)
        if limit is not None:
            local = limit(local)
        P = pose(local)
        err = errors(P)
        conv = jnp.all(err <= tol)
    good = jnp.all(jnp.isfinite(target)) & jnp.all(jnp.isfinite(local)) & jnp.all(jnp.isfinite(P))
    local, P = jnp.where(good, local, local_prev), jnp.where(good, P, P_prev)
    inf = jnp.array(jnp.inf, err.dtype)
    out = IKResult(rotations=local, positions=P, error=jnp.where(good, err, inf), iterations=jnp.where(good, iters, 0),
                   converged=conv & good, reachable=res.reachable & good, trace=jnp.where(good, res.trace, inf))
    return (local, P), out


@functools.partial(jax.jit, static_argnames=("kind", "max_iters", "unroll", "clamp"))
def _track(offsets, targets, local0, tol, max_step, *, kind, max_iters, unroll, clamp):
    J = local0.shape[0]

    def pose(local):
        P, _ = fk_joints(offsets, _joints.split(local, unroll), (), unroll=unroll)
        return _joints.stack(P)

    def frame(prev, target):
        res = _run(offsets, target, prev[0], tol, kind=kind, max_iters=max_iters, unroll=unroll, trace=True)
        return _frame(res, prev, target, tol, max_step, clamp=clamp, pose=pose,
                      errors=lambda P: _quat.safe_norm(_quat.sub(_quat.unstack(P[J - 1]), _quat.unstack(target))))

    _, out = lax.scan(frame, (local0, pose(local0)), targets)
    return out


@functools.partial(jax.jit, static_argnames=("topo", "kind", "max_iters", "clamp"))
def _track_tree(offsets, targets, local0, weights, tol, max_step, table, damping, *, topo, kind, max_iters, clamp):
    """``targets (T, E, 3)``, ``local0 (J, 4)``; layout as ``_track`` (component-first poses).
    ``table``: ``LimitTable`` or ``None``; a clamped pose is projected back onto the limits."""
    J = local0.shape[0]

    def pose(local):
        P, _ = fk_tree(topo.parents, offsets, [_quat.unstack(local[i]) for i in range(J)])
        return _quat.stack([_quat.stack(p) for p in P])

    def errors(P, target):
        return jnp.stack([_quat.safe_norm(_quat.sub(_quat.unstack(P[e]), _quat.unstack(target[k])))
                          for k, e in enumerate(topo.effectors)])

    def frame(prev, target):
        if kind == "lm":
            res = lm_one(offsets, target, prev[0], weights, tol, table, None, None, damping, topo=topo,
                         max_iters=max_iters, trace=True, early_exit=False)
        else:
            res = run_tree(offsets, target, prev[0], weights, tol, table, topo=topo, kind=kind, max_iters=max_iters,
                           trace=True)
        return _frame(res, prev, target, tol, max_step, clamp=clamp, pose=pose, errors=lambda P: errors(P, target),
                      limit=None if table is None else functools.partial(_project_rows, table))

    _, out = lax.scan(frame, (local0, pose(local0)), targets)
    return out


def track(chain: Chain | Skeleton, targets, *, solver="fabrik", rotations=None, effectors=None, weights=None,
          max_iters: int | None = None, tol=None, max_step_angle=None, unroll: bool | None = None) -> IKResult:
    """Follow a trajectory of targets, warm-starting each frame from the previous solution.

    One ``lax.scan`` over frames, as the lab's viewer does frame by frame.

    Args:
      chain: a ``Chain`` (``offsets (J, 3)``) or a ``Skeleton``.
      targets: ``(T, 3)`` one target per frame; on a skeleton ``(T, E, 3)``.
      solver: ``jaxsim.ik.FABRIK(...)`` / ``CCD(...)`` / ``LevenbergMarquardt(...)``, or
        ``"fabrik"`` / ``"ccd"`` / ``"lm"``.
      rotations: ``(J, 4)`` pose before frame 0; ``None`` = rest pose.
      effectors, weights: skeleton only, as in :func:`jaxsim.ik.ccd`.
      max_iters, tol: per-frame solver settings with a solver name (default 100 and 1e-4).
      max_step_angle: if given (radians), each joint's local rotation may change by at
        most this much per frame; the solution is pulled back along the same rotation
        axis (and projected onto the joint limits of a limited skeleton).  This is the lab's answer to frame-to-frame jitter; the price is tracking
        error while the bound is active (reported in ``error``/``converged``).
      unroll: chains: unroll the joint loop (default: rolled, the faster choice for one target).

    Returns:
      ``IKResult`` whose fields have a leading ``T`` axis; ``trace`` is ``(T, max_iters)``
      (the worst effector).  Under ``jit`` a non-finite target cannot raise: that frame
      keeps the previous pose and reports ``error = inf``, ``iterations = 0``,
      ``converged = False``, and later frames go on from the last good pose.
    """
    settings = resolve_settings(solver, max_iters, tol)
    solver, max_iters, tol = settings.kind, settings.max_iters, settings.tol
    check_settings(chain, solver, max_iters, tol)
    if solver == "lm" and not isinstance(chain, Skeleton):
        chain = Skeleton.from_chain(chain)
        res = track(chain, jnp.asarray(targets)[:, None], solver=settings, rotations=rotations,
                    max_step_angle=max_step_angle)
        return IKResult(rotations=res.rotations, positions=res.positions, error=res.error[:, 0],
                        iterations=res.iterations, converged=res.converged, reachable=res.reachable[:, 0],
                        trace=res.trace)
    dtype = chain.offsets.dtype
    J = chain.num_joints
    if max_step_angle is not None and is_concrete(max_step_angle):
        check_real("max_step_angle", max_step_angle, minimum=0.0, strict=True)
    max_step = jnp.asarray(np.pi if max_step_angle is None else max_step_angle, dtype)
    if isinstance(chain, Skeleton):
        effectors, targets, rotations, weights = check_tree_inputs(chain, targets, rotations, effectors, weights)
        if targets.ndim != 3:
            raise ValueError(f"targets must have shape (T, E, 3), got {targets.shape}")
        if rotations.shape != (J, 4):
            raise ValueError(f"rotations must have shape ({J}, 4), got {rotations.shape}")
        res = _track_tree(chain.offsets, targets, rotations, weights, jnp.asarray(tol, dtype),
                          max_step, limit_table(chain), jnp.asarray(getattr(settings, "damping", 0.0), dtype), topo=topology(chain.parents, effectors), kind=solver,
                          max_iters=int(max_iters),
                          clamp=max_step_angle is not None)
        return res
    if effectors is not None or weights is not None:
        raise ValueError("effectors and weights are for a Skeleton; a Chain's effector is its last joint")
    targets = jnp.asarray(targets, dtype)
    if targets.ndim != 2 or targets.shape[-1] != 3:
        raise ValueError(f"targets must have shape (T, 3), got {targets.shape}")
    if is_concrete(targets):
        check_finite("targets", targets)
    rotations = chain.rest_rotations() if rotations is None else jnp.asarray(rotations, dtype)
    if rotations.shape != (J, 4):
        raise ValueError(f"rotations must have shape ({J}, 4), got {rotations.shape}")
    _check_target_and_rotations(chain, targets, rotations)
    rotations = _quat.unit_quaternions(rotations)
    return _track(chain.offsets, targets, rotations, jnp.asarray(tol, dtype), max_step, kind=solver,
                  max_iters=int(max_iters), unroll=_joints.unrolled(J, unroll, 1), clamp=max_step_angle is not None)
