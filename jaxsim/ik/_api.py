"""The public IK entry points: ``ccd``, ``fabrik`` and ``solve``, on chains and on skeletons.

A ``Chain`` goes to the chain driver (``_solve``); a ``Skeleton`` to the tree driver
(``_tree_solve``), except a chain-shaped skeleton whose only effector is its last joint,
which is solved as the ``Chain`` it is.
"""

from __future__ import annotations

import jax.numpy as jnp

from .._dataclass import in_reverse_mode
from .._validate import check_bool
from ._chain import Chain
from ._result import IKResult
from ._settings import CCD, FABRIK, resolve_settings
from ._skeleton import Skeleton, check_effectors
from ._solve import _solve, check_settings
from ._tree_solve import solve_tree


def _as_chain(skeleton: Skeleton, effectors, weights):
    """The ``Chain`` a free skeleton is, when it is a chain solved for its end alone; else ``None``."""
    if (skeleton.is_chain and skeleton.limits is None and weights is None
            and check_effectors(skeleton, effectors) == (skeleton.num_joints - 1,)):
        return Chain(skeleton.offsets)
    return None


def _chain_result(res: IKResult) -> IKResult:
    """A one-effector tree result with the chain's shapes (``error``, ``reachable`` ``(...)``)."""
    return IKResult(rotations=res.rotations, positions=res.positions, error=res.error[..., 0],
                    iterations=res.iterations, converged=res.converged, reachable=res.reachable[..., 0],
                    trace=res.trace, angle_error=None if res.angle_error is None else res.angle_error[..., 0])


def _dispatch(settings, model, targets, rotations, *, effectors, weights, trace, unroll, early_exit=False,
              implicit_diff=False, sharded=False, orientations=None, orientation_weights=None) -> IKResult:
    kind, max_iters, tol = settings.kind, settings.max_iters, settings.tol
    check_settings(model, kind, max_iters, tol)
    for name, flag in (("trace", trace), ("early_exit", early_exit), ("implicit_diff", implicit_diff)):
        check_bool(name, flag)
    if early_exit and not implicit_diff and in_reverse_mode(model, targets, rotations, orientations, weights):
        raise ValueError("early_exit=True runs the sweeps in a lax.while_loop, which JAX differentiates in forward "
                         "mode only (jax.jvp, jax.jacfwd); for jax.grad use early_exit=False (the default scan), or "
                         "implicit_diff=True, which never differentiates the sweeps")
    tree_kw = dict(trace=trace, early_exit=early_exit, implicit_diff=implicit_diff, orientations=orientations,
                   orientation_weights=orientation_weights)
    if isinstance(model, Chain):
        if effectors is not None or weights is not None:
            raise ValueError("effectors and weights are for a Skeleton; a Chain's effector is its last joint")
        if kind == "lm" or orientations is not None:  # the tree driver, with the end as the one effector
            if sharded:
                raise ValueError("sharded=True is supported for the chain FABRIK and CCD kernels only")
            targets = jnp.asarray(targets, model.offsets.dtype)
            if targets.ndim < 1 or targets.shape[-1] != 3:
                raise ValueError(f"target must have shape (..., 3), got {targets.shape}")
            if orientations is not None:
                orientations = jnp.asarray(orientations, model.offsets.dtype)[..., None, :]
                tree_kw["orientations"] = orientations
            res = solve_tree(settings, Skeleton.from_chain(model), targets[..., None, :], rotations,
                             effectors=(model.num_joints - 1,), weights=None, **tree_kw)
            return _chain_result(res)
        return _solve(kind, model, targets, rotations, max_iters=max_iters, tol=tol, trace=trace, unroll=unroll,
                      early_exit=early_exit, implicit_diff=implicit_diff, sharded=sharded)
    chain = None if (kind == "lm" or orientations is not None) else _as_chain(model, effectors, weights)
    if chain is None:
        if sharded:
            raise ValueError("sharded=True is supported for chains only; split a skeleton batch yourself")
        return solve_tree(settings, model, targets, rotations, effectors=effectors, weights=weights, **tree_kw)
    targets = jnp.asarray(targets, model.offsets.dtype)
    if targets.ndim < 2 or targets.shape[-2:] != (1, 3):
        raise ValueError(f"targets must have shape (..., 1, 3) for 1 effector, got {targets.shape}")
    res = _solve(kind, chain, targets[..., 0, :], rotations, max_iters=max_iters, tol=tol, trace=trace,
                 unroll=unroll, early_exit=early_exit, implicit_diff=implicit_diff, sharded=sharded)
    return IKResult(rotations=res.rotations, positions=res.positions, error=res.error[..., None],
                    iterations=res.iterations, converged=res.converged, reachable=res.reachable[..., None],
                    trace=res.trace)


def ccd(chain: Chain | Skeleton, target, rotations=None, *, effectors=None, weights=None, max_iters: int = 100,
        tol=1e-4, trace: bool = True, unroll: bool | None = None, implicit_diff: bool = False, orientations=None,
        orientation_weights=None) -> IKResult:
    """Cyclic coordinate descent IK (Wang & Chen 1991; on trees, Horn 1987 per joint).

    Args:
      chain: a ``Chain`` (``offsets (J, 3)``) or a ``Skeleton``.
      target: chain: ``(3,)`` world target, or ``(..., 3)`` for a batch; skeleton:
        ``(E, 3)`` or ``(..., E, 3)``, one per effector.
      rotations: ``(J, 4)`` (or ``(..., J, 4)``) local start rotations; ``None`` = rest pose.
      effectors: skeleton only: joint ids or names (default: the leaves).
      weights: skeleton only: ``(E,)`` positive effector weights (default ones).
      max_iters: number of sweeps scanned (static; a new value recompiles).
      tol: converged when every effector is within ``tol`` of its target (scene units).
      trace: also return the per-sweep error ``trace (..., max_iters)`` (the worst effector).
      unroll: chains: unroll the loop over joints (default: ``J <= 16`` and a batch of
        >= 256).  Trees are always unrolled over their static joints.
      implicit_diff: differentiate the returned solution by the implicit function
        theorem at the solution (``jaxsim.ik._implicit``) instead of through the
        unrolled sweeps: no memory per sweep, least-change rotations derivative.
        Free skeletons without orientation targets only.
      orientations: ``(E, 4)`` (or ``(..., E, 4)``; a chain: ``(4,)``/``(..., 4)``) unit
        quaternions, the effectors' target world orientations; ``None`` = positions only.
      orientation_weights: ``(E,)`` scene units per radian (default 0.1): the angle error
        weighs as ``weight * angle``, and ``converged`` needs it within ``tol`` too.

    Returns:
      ``IKResult``; on a skeleton ``error`` and ``reachable`` are ``(..., E)``.  Sweeps
      after convergence are masked no-ops.  By default ``jax.grad`` and ``jax.jvp``
      differentiate through every sweep of the scan (with respect to the targets, the
      offsets and the start rotations).
    """
    return _dispatch(CCD(max_iters, tol), chain, target, rotations, effectors=effectors, weights=weights,
                     trace=trace, unroll=unroll, implicit_diff=implicit_diff, orientations=orientations,
                     orientation_weights=orientation_weights)


def fabrik(chain: Chain | Skeleton, target, rotations=None, *, effectors=None, weights=None, max_iters: int = 100,
           tol=1e-4, trace: bool = True, unroll: bool | None = None, implicit_diff: bool = False, orientations=None,
           orientation_weights=None) -> IKResult:
    """FABRIK IK (Aristidou & Lasenby 2011; §4.2 on trees), rotations rebuilt from the positions.

    Arguments and result as for :func:`ccd`.  On a chain an unreachable target gets the
    straight chain towards it after one sweep, with ``converged=False``; a symmetric
    start pose (on the line of its target) is bent first.  On a tree the sweeps start
    from the given pose as it is, and each sub-base turns its child bones rigidly.
    """
    return _dispatch(FABRIK(max_iters, tol), chain, target, rotations, effectors=effectors, weights=weights,
                     trace=trace, unroll=unroll, implicit_diff=implicit_diff, orientations=orientations,
                     orientation_weights=orientation_weights)


def solve(chain: Chain | Skeleton, targets, *, solver="fabrik", rotations=None, effectors=None, weights=None,
          max_iters: int | None = None, tol=None, trace: bool = False, unroll: bool | None = None,
          early_exit: bool = False, implicit_diff: bool = False, sharded: bool | None = None, orientations=None,
          orientation_weights=None) -> IKResult:
    """Batched IK over any leading shape of ``targets`` (``(..., 3)``, or ``(..., E, 3)`` on a skeleton).

    ``solver`` is a settings object, ``jaxsim.ik.FABRIK(max_iters=, tol=)``,
    ``jaxsim.ik.CCD(...)`` or ``jaxsim.ik.LevenbergMarquardt(..., damping=)``, or the
    shorthand ``"fabrik"`` / ``"ccd"`` / ``"lm"`` with ``max_iters`` (default 100) and
    ``tol`` (default 1e-4) given here.  ``orientations`` and ``orientation_weights``
    are as for :func:`ccd`.  On a skeleton with limits every returned pose is within
    them (``jaxsim.ik.limit_violation``), and with limits or orientation targets FABRIK
    and CCD return the best pose they visited (never one worse than the start), while
    ``iterations`` counts the sweeps run.

    ``rotations`` may be ``(J, 4)`` (shared start pose) or ``(..., J, 4)``.  The batch
    trails in memory inside the kernel, so a large batch is one elementwise loop per
    joint update.  Per-sweep traces are off by default to save memory.

    ``early_exit=True`` runs the sweeps in a ``lax.while_loop`` that stops as soon as
    every element of the batch is done, instead of the fixed-length scan.  Results are
    identical; it is much faster when ``tol > 0`` and most targets converge well before
    ``max_iters``, but it supports forward-mode differentiation only (``jax.grad``
    needs the default scan, or ``implicit_diff=True``, which never differentiates the
    sweeps and so combines with ``early_exit``).

    ``sharded=None`` splits a chain's batch across all local devices when there are
    several (``jax.sharding.NamedSharding`` over a 1-D mesh; see ``jaxsim._sharding``);
    on one device it does nothing.  ``True`` insists, ``False`` keeps the batch on one device.
    """
    return _dispatch(resolve_settings(solver, max_iters, tol), chain, targets, rotations, effectors=effectors,
                     weights=weights, trace=trace, unroll=unroll, early_exit=early_exit, implicit_diff=implicit_diff,
                     sharded=sharded, orientations=orientations, orientation_weights=orientation_weights)
