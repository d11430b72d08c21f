"""The result type shared by every IK solver."""

from __future__ import annotations

import jax

from .._dataclass import pytree_dataclass


@pytree_dataclass
class IKResult:
    """Solution and diagnostics of an IK solve.

    Shapes are for one target; batched entry points (``solve``, ``track``, ``vmap``) add
    leading batch axes ``(...)`` to every field.

    Attributes:
      rotations: ``(J, 4)`` local unit quaternions (w, x, y, z) of the solution.
      positions: ``(J, 3)`` joint world positions, exactly ``fk(chain, rotations).positions``.
      error: ``()`` distance ``|end - target|`` of the returned pose (scene units).
      iterations: ``()`` int32, sweeps actually performed (0 if the start pose was already
        within ``tol``).  A CCD sweep goes tip to root once; a FABRIK sweep is a backward
        plus a forward pass; FABRIK's straight-line answer for an unreachable target is 1.
      converged: ``()`` bool, ``error <= tol``.
      reachable: ``()`` bool, ``|target - root| <= reach``.
      trace: ``(max_iters,)`` error after each sweep (held constant once stopped), or
        ``None`` when the solver was called with ``trace=False``.  With orientation
        targets it is the worst of the position errors and the weighted angle errors.
      angle_error: ``(E,)`` angle (rad) between each effector's frame and its target
        orientation, or ``None`` without orientation targets.  ``converged`` then also
        needs ``orientation_weight * angle_error <= tol``.
    """

    rotations: jax.Array
    positions: jax.Array
    error: jax.Array
    iterations: jax.Array
    converged: jax.Array
    reachable: jax.Array
    trace: jax.Array | None
    angle_error: jax.Array | None = None
