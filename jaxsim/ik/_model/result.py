"""The result type shared by every IK solver."""

from __future__ import annotations

import jax

from ..._dataclass import pytree_dataclass


@pytree_dataclass
class IKResult:
    """Solution and diagnostics of an IK solve, the same on every model and solver.

    Shapes are for one target set; batched entry points (``solve``, ``track``, ``vmap``)
    add leading batch axes ``(...)`` to every field.  ``E`` is the number of effectors
    (1 on a chain solved for its end).

    Attributes:
      rotations: ``(J, 4)`` local unit quaternions (w, x, y, z) of the solution.
      positions: ``(J, 3)`` joint world positions, exactly ``fk(model, rotations).positions``.
      error: ``(E,)`` distance ``|effector - target|`` of the returned pose (scene units).
      iterations: ``()`` int32, sweeps actually performed (0 if the start pose was already
        within ``tol``).  A CCD sweep goes tip to root once; a FABRIK sweep is a backward
        plus a forward pass; FABRIK's straight-line answer for an unreachable target on
        a chain is 1; an LM iteration is one trial step, accepted or not.
      converged: ``()`` bool, every effector within ``tol`` (and every weighted angle
        error, with orientation targets).
      reachable: ``(E,)`` bool, each target within the summed bone lengths of its
        effector's path from the root.
      trace: ``(max_iters,)`` the worst effector's error after each sweep (held constant
        once stopped), or ``None`` when the solver was called with ``trace=False``.  With
        orientation targets it is the worst of the position errors and the weighted
        angle errors.
      angle_error: ``(E,)`` angle (rad) between each effector's frame and its target
        orientation, or ``None`` without orientation targets.
      stationary: Levenberg–Marquardt only (else ``None``): ``()`` bool, converged, or
        stopped at a stationary point of its least squares within the limits (no descent
        direction left; ``_solvers.lm.is_stationary``).  False means it ran out of
        iterations on the way: its pose is not a minimum, and an implicit derivative
        (``implicit_diff=True``, which assumes one) is not that of a solution.
    """

    rotations: jax.Array
    positions: jax.Array
    error: jax.Array
    iterations: jax.Array
    converged: jax.Array
    reachable: jax.Array
    trace: jax.Array | None
    angle_error: jax.Array | None = None
    stationary: jax.Array | None = None
