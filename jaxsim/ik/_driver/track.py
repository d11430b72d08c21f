"""Tracking a target trajectory frame by frame, warm-started, with optional jitter control."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from ..._dataclass import is_concrete
from ..._validate import check_real
from ..._geometry import quat as _quat
from .._model import joints as _joints
from .._model.fk import joint_positions
from .inputs import check_flags, check_inputs, check_model
from .kernel import bent_start, run_chain, run_tree
from .._model.limits import limit_table
from .._model.stacked import project_stacked
from .._solvers.lm import lm_one
from .._model.result import IKResult
from .._solvers.settings import LevenbergMarquardt, resolve_settings
from .._model.skeleton import topology
from .solve import lean_chain


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
    """``(J, 4)`` rotations projected onto the limits (all joints at once, ``stacked``)."""
    return project_stacked(table, local)


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


@functools.partial(jax.jit, static_argnames=("topo", "alg", "lean", "max_iters", "unroll", "clamp"))
def _track(offsets, targets, local0, weights, tol, max_step, table, damping, *, topo, alg, lean, max_iters, unroll,
           clamp):
    """``targets (T, E, 3)``, ``local0 (J, 4)``; each frame is the kernel ``solve`` selects
    (``lean``: the chain kernel), in the component-first layout with an empty batch.
    ``table``: ``LimitTable`` or ``None``; a clamped pose is projected back onto the limits."""
    effectors = np.asarray(topo.effectors)

    def pose(local):
        return joint_positions(topo.parents, offsets, local)

    def frame(prev, target):
        if lean:
            res = run_chain(offsets, target[0], prev[0], tol, alg=alg, max_iters=max_iters, unroll=unroll, trace=True)
        elif alg is LevenbergMarquardt:
            res = lm_one(offsets, target, prev[0], weights, tol, table, None, None, damping, topo=topo,
                         max_iters=max_iters, trace=True, early_exit=False)
        else:
            start = bent_start(offsets, target, prev[0], tol, topo=topo)
            res = run_tree(offsets, target, start, weights, tol, table, topo=topo, alg=alg, max_iters=max_iters,
                           trace=True)
        return _frame(res, prev, target, tol, max_step, clamp=clamp, pose=pose,
                      errors=lambda P: jnp.sqrt(jnp.sum((P[effectors] - target) ** 2, axis=-1)),
                      limit=None if table is None else functools.partial(_project_rows, table))

    _, out = lax.scan(frame, (local0, pose(local0)), targets)
    return out


def track(model, targets, *, solver="fabrik", rotations=None, effectors=None, weights=None,
          max_iters: int | None = None, tol=None, max_step_angle=None, unroll: bool | None = None) -> IKResult:
    """Follow a trajectory of targets, warm-starting each frame from the previous solution.

    One ``lax.scan`` over frames, as the lab's viewer does frame by frame.

    Args:
      model: a ``Skeleton`` (a chain is one).
      targets: ``(T, E, 3)`` one target per effector and frame.
      solver: ``jaxsim.ik.FABRIK(...)`` / ``CCD(...)`` / ``LevenbergMarquardt(...)``, or
        ``"fabrik"`` / ``"ccd"`` / ``"lm"``.
      rotations: ``(J, 4)`` pose before frame 0; ``None`` = rest pose.
      effectors, weights: as in :func:`jaxsim.ik.solve`.
      max_iters, tol: per-frame solver settings with a solver name (default 100 and 1e-4).
      max_step_angle: if given (radians), each joint's local rotation may change by at
        most this much per frame; the solution is pulled back along the same rotation
        axis (and projected onto the joint limits of a limited skeleton).  This is the
        lab's answer to frame-to-frame jitter; the price is tracking error while the
        bound is active (reported in ``error``/``converged``).
      unroll: chains: unroll the joint loop (default: rolled, the faster choice for one target).

    Returns:
      ``IKResult`` whose fields have a leading ``T`` axis (``error (T, E)``); ``trace`` is
      ``(T, max_iters)`` (the worst effector).  Under ``jit`` a non-finite target cannot
      raise: that frame keeps the previous pose and reports ``error = inf``,
      ``iterations = 0``, ``converged = False``, and later frames go on from the last
      good pose.
    """
    settings = resolve_settings(solver, max_iters, tol)
    check_model(model, settings)
    check_flags(("unroll",), unroll=unroll)
    inp = check_inputs(model, targets, rotations, effectors, weights)
    J, dtype = model.num_joints, model.offsets.dtype
    if inp.targets.ndim != 3:
        raise ValueError(f"targets must have shape (T, E, 3), got {inp.targets.shape}")
    if inp.rotations.shape != (J, 4):
        raise ValueError(f"rotations must have shape ({J}, 4), got {inp.rotations.shape}")
    if max_step_angle is not None and is_concrete(max_step_angle):
        check_real("max_step_angle", max_step_angle, minimum=0.0, strict=True)
    max_step = jnp.asarray(np.pi if max_step_angle is None else max_step_angle, dtype)
    table = limit_table(model)
    topo = topology(model.parents, inp.effectors)
    return _track(model.offsets, inp.targets, inp.rotations, inp.weights, jnp.asarray(settings.tol, dtype), max_step,
                  table, jnp.asarray(getattr(settings, "damping", 0.0), dtype), topo=topo, alg=type(settings),
                  lean=lean_chain(settings, topo, table, None), max_iters=int(settings.max_iters),
                  unroll=_joints.unrolled(J, unroll, 1), clamp=max_step_angle is not None)
