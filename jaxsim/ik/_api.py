"""The public IK entry points: ``solve``, and ``ccd`` and ``fabrik``, which are ``solve`` with fixed settings."""

from __future__ import annotations

from ._result import IKResult
from ._settings import CCD, FABRIK, DEFAULT_MAX_ITERS, DEFAULT_TOL, resolve_settings
from ._solve import solve_ik


def solve(model, targets, *, solver=None, rotations=None, effectors=None, weights=None,
          max_iters: int | None = None, tol=None, trace: bool = False, unroll: bool | None = None,
          early_exit: bool = False, implicit_diff: bool = False, sharded: bool | None = None, orientations=None,
          orientation_weights=None, poles=None) -> IKResult:
    """Batched IK on a ``Skeleton`` (a chain is one) over any leading shape of ``targets``.

    Args:
      model: a ``Skeleton``; ``jaxsim.ik.Chain``, ``lab_arm`` and ``straight_chain``
        build chains, ``humanoid`` a 24-joint body.
      targets: ``(..., E, 3)`` world targets, one per effector; with one effector a
        single ``(3,)`` target is read as ``(1, 3)``.
      solver: a settings object, ``jaxsim.ik.FABRIK(max_iters=, tol=)``,
        ``jaxsim.ik.CCD(...)`` or ``jaxsim.ik.LevenbergMarquardt(..., damping=, seeds=)``, or
        the shorthand ``"fabrik"`` / ``"ccd"`` / ``"lm"`` with ``max_iters`` (default 100)
        and ``tol`` (default 1e-4, scene units: converged when every effector is within
        it).  ``None`` (the default): ``"lm"`` for a skeleton with limits or with
        orientation targets, where the sweep solvers fall short (docs/ik.md), else
        ``"fabrik"``.
      rotations: ``(J, 4)`` (one start pose for the batch) or ``(..., J, 4)`` local
        start rotations; ``None`` = rest pose (for LM, the rest pose with every hinge
        at the middle of its range: at rest a hinge is often on a bound and straight).
      effectors: joint ids or names (default: the leaves; a chain's last joint).
      weights: ``(E,)`` positive effector weights (default ones).
      trace: also return ``trace (..., max_iters)``, the worst effector's error after
        each sweep (off by default to save memory).
      unroll: chains: unroll the loop over joints (default: ``J <= 16`` and a batch of
        >= 256), else a ``fori_loop``.  Other trees are unrolled over their static joints.
      early_exit: run the sweeps in a ``lax.while_loop`` that stops once every element
        is done, instead of the fixed-length scan: same results, faster when most
        targets converge early, forward-mode differentiation only.
      implicit_diff: differentiate the returned solution by the implicit function
        theorem (``jaxsim.ik._implicit``) instead of through the sweeps: no memory per
        sweep, least-change rotations derivative.  With limits the bounds the solution
        sits on are held; orientation targets are differentiated too.
      sharded: ``None`` splits a chain's batch across all local devices when there are
        several (``jaxsim._sharding``); ``True`` insists, ``False`` keeps one device.
      orientations: ``(..., E, 4)`` unit quaternions, the effectors' target world
        orientations; ``None`` = positions only.
      orientation_weights: ``(E,)`` scene units per radian (default 0.1): the angle error
        weighs as ``weight * angle``, and ``converged`` needs it within ``tol`` too.
      poles: ``{joint: point (..., 3)}``, LM only: each named middle joint of a limb (an
        elbow, a knee: the limb runs from its parent to the one effector below it, its
        child or grandchild) bends
        toward its pole point, into the half-plane of the line from the limb's root to its
        end and the pole.  A pole's residual (the chord from the middle joint to that
        half-plane, scene units) joins LM's, and ``converged`` needs it within ``tol`` too.
        LM's start turns each hinge limb toward its pole (as :func:`two_bone`).

    Returns:
      ``IKResult`` with ``error``, ``reachable`` and ``angle_error`` ``(..., E)``.  Sweeps
      after convergence are masked no-ops.  With limits every returned pose is within
      them, and with limits or orientation targets FABRIK and CCD return the best pose
      they visited (never one worse than the start).  By default ``jax.grad`` and
      ``jax.jvp`` differentiate through every sweep (with respect to the targets, the
      offsets and the start rotations).
    """
    if solver is None:
        lm = getattr(model, "limits", None) is not None or orientations is not None or poles is not None
        solver = "lm" if lm else "fabrik"
    return solve_ik(resolve_settings(solver, max_iters, tol), model, targets, rotations=rotations,
                    effectors=effectors, weights=weights, orientations=orientations,
                    orientation_weights=orientation_weights, trace=trace, unroll=unroll, early_exit=early_exit,
                    implicit_diff=implicit_diff, sharded=sharded, poles=poles)


def ccd(model, targets, *, rotations=None, effectors=None, weights=None, max_iters: int = DEFAULT_MAX_ITERS,
        tol=DEFAULT_TOL, trace: bool = False, unroll: bool | None = None, early_exit: bool = False,
        implicit_diff: bool = False, sharded: bool | None = None, orientations=None,
        orientation_weights=None) -> IKResult:
    """Cyclic coordinate descent IK (Wang & Chen 1991; on trees, Horn 1987 per joint):
    :func:`solve` with ``solver=CCD(max_iters, tol)``."""
    return solve(model, targets, solver=CCD(max_iters, tol), rotations=rotations, effectors=effectors,
                 weights=weights, trace=trace, unroll=unroll, early_exit=early_exit, implicit_diff=implicit_diff,
                 sharded=sharded, orientations=orientations, orientation_weights=orientation_weights)


def fabrik(model, targets, *, rotations=None, effectors=None, weights=None, max_iters: int = DEFAULT_MAX_ITERS,
           tol=DEFAULT_TOL, trace: bool = False, unroll: bool | None = None, early_exit: bool = False,
           implicit_diff: bool = False, sharded: bool | None = None, orientations=None,
           orientation_weights=None) -> IKResult:
    """FABRIK IK (Aristidou & Lasenby 2011; §4.2 on trees), rotations rebuilt from the
    positions: :func:`solve` with ``solver=FABRIK(max_iters, tol)``.  On a chain an
    unreachable target gets the straight chain towards it after one sweep, with
    ``converged=False``; a start pose on the line of its target is bent first (§5.4)."""
    return solve(model, targets, solver=FABRIK(max_iters, tol), rotations=rotations, effectors=effectors,
                 weights=weights, trace=trace, unroll=unroll, early_exit=early_exit, implicit_diff=implicit_diff,
                 sharded=sharded, orientations=orientations, orientation_weights=orientation_weights)
