"""The public IK entry points: ``solve``, and ``ccd`` and ``fabrik``, which are ``solve`` with fixed settings."""

from __future__ import annotations

import dataclasses
import warnings

from .._model.result import IKResult
from .._solvers.settings import CCD, FABRIK, resolve_settings
from .solve import solve_ik

def _moved(settings, moved: dict):
    """``settings`` with the options given to ``solve`` the old way (a warning names the new spelling)."""
    given = {k: v for k, v in moved.items() if v is not None and not (k in ("trace", "implicit_diff") and v is False)}
    if not given:
        return settings
    name = type(settings).__name__
    warnings.warn(f"solve({', '.join(f'{k}=' for k in given)}) moved onto the solver's settings: pass "
                  f"solver=jaxsim.ik.{name}(..., {', '.join(f'{k}={v!r}' for k, v in given.items())})",
                  DeprecationWarning, stacklevel=3)
    if "unroll" in given and not hasattr(settings, "unroll"):
        raise ValueError(f"unroll applies to FABRIK and CCD (the joint loop of a chain), not to {name}")
    return dataclasses.replace(settings, **given)


def solve(model, targets, *, solver=None, rotations=None, effectors=None, weights=None, orientations=None,
          orientation_weights=None, poles=None, sharded: bool | None = None, max_iters: int | None = None, tol=None,
          trace=None, unroll=None, early_exit=None, implicit_diff=None) -> IKResult:
    """Batched IK on a ``Skeleton`` (a chain is one) over any leading shape of ``targets``.

    Args:
      model: a ``Skeleton``; ``jaxsim.ik.Chain``, ``lab_arm`` and ``straight_chain``
        build chains, ``humanoid`` a 24-joint body.
      targets: ``(..., E, 3)`` world targets, one per effector.  With one effector the
        last axis is the target: ``(3,)`` is one target and ``(N, 3)`` is ``N`` of them
        (read as ``(N, 1, 3)``; a model with several effectors refuses it).
      solver: a settings object, ``jaxsim.ik.FABRIK(max_iters, tol, early_exit=, trace=,
        implicit_diff=, unroll=)``, ``jaxsim.ik.CCD(...)`` or
        ``jaxsim.ik.LevenbergMarquardt(..., damping=, seeds=)``, or the shorthand
        ``"fabrik"`` / ``"ccd"`` / ``"lm"`` with ``max_iters`` (default 100) and ``tol``
        (default 1e-4, scene units: converged when every effector is within it).
        ``None`` (the default): ``"lm"`` for a skeleton with limits, orientation targets
        or poles, where the sweep solvers fall short (docs/ik.md), else ``"fabrik"``.
        The settings' ``early_exit`` (default: stop once the batch is done, and the
        fixed-length scan where the call is differentiated), ``trace`` and
        ``implicit_diff`` are documented on :class:`jaxsim.ik.FABRIK`.
      rotations: ``(J, 4)`` (one start pose for the batch) or ``(..., J, 4)`` local
        start rotations; ``None`` = rest pose (for LM, the rest pose with every hinge
        at the middle of its range: at rest a hinge is often on a bound and straight).
      effectors: joint ids or names (default: the leaves; a chain's last joint).
      weights: ``(E,)`` positive effector weights (default ones).
      orientations: ``(..., E, 4)`` unit quaternions, the effectors' target world
        orientations; ``None`` = positions only.
      orientation_weights: ``(E,)`` scene units per radian (default 0.1): the angle error
        weighs as ``weight * angle``, and ``converged`` needs it within ``tol`` too.
      poles: ``{joint: point (..., 3)}``, LM only: each named middle joint of a limb (an
        elbow, a knee: the limb runs from its parent to the one effector below it, its
        child or grandchild) bends toward its pole point, into the half-plane of the line
        from the limb's root to its end and the pole.  A pole's residual (the chord from
        the middle joint to that half-plane, scene units) joins LM's, and ``converged``
        needs it within ``tol`` too.  LM's start turns each hinge limb toward its pole
        (as :func:`two_bone`).
      sharded: ``None`` splits a chain's batch across all local devices when there are
        several (``jaxsim._sharding``); ``True`` insists, ``False`` keeps one device.
      max_iters, tol: with a solver name (or none), the settings' two numbers.
      trace, unroll, early_exit, implicit_diff: moved onto the settings objects; still
        taken here for one release, with a ``DeprecationWarning``.

    Returns:
      ``IKResult`` with ``error``, ``reachable`` and ``angle_error`` ``(..., E)``.  Sweeps
      after convergence are masked no-ops.  With limits every returned pose is within
      them, and with limits or orientation targets FABRIK and CCD return the best pose
      they visited (never one worse than the start).  ``jax.grad`` and ``jax.jvp``
      differentiate through every sweep (with respect to the targets, the offsets and the
      start rotations), or by the implicit function theorem with ``implicit_diff``.
    """
    if solver is None:
        lm = getattr(model, "limits", None) is not None or orientations is not None or poles is not None
        solver = "lm" if lm else "fabrik"
    settings = _moved(resolve_settings(solver, max_iters, tol),
                      dict(trace=trace, unroll=unroll, early_exit=early_exit, implicit_diff=implicit_diff))
    return solve_ik(settings, model, targets, rotations=rotations, effectors=effectors, weights=weights,
                    orientations=orientations, orientation_weights=orientation_weights, sharded=sharded, poles=poles)


def ccd(model, targets, *, rotations=None, effectors=None, weights=None, orientations=None, orientation_weights=None,
        sharded: bool | None = None, **settings) -> IKResult:
    """Cyclic coordinate descent IK (Wang & Chen 1991; on trees, Horn 1987 per joint):
    :func:`solve` with ``solver=CCD(**settings)`` (``max_iters``, ``tol``, ``early_exit``,
    ``trace``, ``implicit_diff``, ``unroll``)."""
    return solve(model, targets, solver=CCD(**settings), rotations=rotations, effectors=effectors, weights=weights,
                 sharded=sharded, orientations=orientations, orientation_weights=orientation_weights)


def fabrik(model, targets, *, rotations=None, effectors=None, weights=None, orientations=None,
           orientation_weights=None, sharded: bool | None = None, **settings) -> IKResult:
    """FABRIK IK (Aristidou & Lasenby 2011; §4.2 on trees), rotations rebuilt from the
    positions: :func:`solve` with ``solver=FABRIK(**settings)`` (as :func:`ccd`).  On a
    chain an unreachable target gets the straight chain towards it after one sweep, with
    ``converged=False``; a start pose on the line of its target is bent first (§5.4)."""
    return solve(model, targets, solver=FABRIK(**settings), rotations=rotations, effectors=effectors, weights=weights,
                 sharded=sharded, orientations=orientations, orientation_weights=orientation_weights)

