"""LM's start poses: the default start, and the extra starts of a multi-start solve.

A solve with ``LevenbergMarquardt(seeds=K)`` runs LM from ``K`` starts per target set
(the given or default start, and ``K - 1`` fixed poses drawn inside the limits, shared
by every set) and keeps, per set, the first start that converged, or the one with the
least worst position error when none did.  The starts are drawn once, by NumPy, from fixed seeds, so
a solve is deterministic.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..._geometry import quat as _quat
from .._model.limits import Hinge
from .._model.limit_checks import project_limits
from .._model.result import IKResult

#: Rotation amplitudes (rad) of the extra starts, in turn.
SEED_AMPLITUDES = (0.5, 1.0, 1.5)
#: Where in its range each hinge of the extra starts sits, in turn (fractions of ``[lo, hi]``):
#: spread over the range, since the limited humanoid's failures are mostly limb configurations
#: (docs/notebook.md: ``seeds=8`` 97.0% -> 97.8% converged against hinges turned at random).
#: A limb's hinge is then set again by LM's limb start (``limb_start``); these fractions stay
#: for the hinges that are in no limb (a chain of hinges).
HINGE_FRACTIONS = (0.1, 0.9, 0.3, 0.7, 0.2, 0.8, 0.4, 0.6)
#: The swivel (rad) of start ``k``'s limbs about their target lines (``limb_start``), ``k % 8``:
#: the elbow or knee on another side.  On the limited humanoid, ``seeds=8``: 97.3% converged with
#: every swivel 0, 98.5% with these (docs/notebook.md).
SWIVELS = (0.0, 1.2, -1.2, 2.4, -2.4, 3.14159, 0.6, -0.6)


def default_start(skeleton):
    """LM's start when none is given: ``(J, 4)`` (NumPy), the rest pose with every hinge turned to
    the middle of its range.

    A hinge at rest often sits on a bound with its limb straight (the humanoid's elbows
    and knees, range ``[0, 150]`` degrees): a singular start on the edge of the set.  From
    mid-range the limited humanoid's 1,000 sets converge 81% against 62% from rest
    (docs/notebook.md, "LM on stacked poses").
    """
    q = np.zeros((skeleton.num_joints, 4))
    q[:, 0] = 1.0
    for i, lim in enumerate(skeleton.limits or ()):
        if isinstance(lim, Hinge):
            half = 0.25 * (lim.lo + lim.hi)
            q[i] = (np.cos(half), *(np.sin(half) * np.asarray(lim.axis)))
    return q.astype(skeleton.offsets.dtype)  # NumPy: a constant even when called inside a trace


def extra_starts(skeleton, seeds: int):
    """``(seeds - 1, J, 4)`` fixed start poses inside the limits: per joint a rotation about
    a random axis by up to ``SEED_AMPLITUDES[k % 3]`` radians, after the default start, projected;
    every hinge of start ``k`` at ``HINGE_FRACTIONS[k % 8]`` of its range."""
    J, out = skeleton.num_joints, []
    for k in range(1, seeds):
        rng = np.random.default_rng(1000 + k)
        ax = rng.normal(size=(J, 3))
        ax /= np.linalg.norm(ax, axis=-1, keepdims=True)
        half = 0.5 * SEED_AMPLITUDES[(k - 1) % len(SEED_AMPLITUDES)] * rng.uniform(size=(J, 1))
        out.append(np.concatenate([np.cos(half), np.sin(half) * ax], axis=-1))
    dtype = skeleton.offsets.dtype
    turn = _quat.unstack(jnp.asarray(np.stack(out), dtype), axis=-1)  # (seeds - 1, J) components
    base = _quat.unstack(jnp.asarray(default_start(skeleton)), axis=-1)
    starts = _quat.stack(_quat.mul(base, turn), axis=-1)
    if skeleton.limits is None:
        return starts
    starts = project_limits(skeleton, starts)
    for k in range(seeds - 1):
        f = HINGE_FRACTIONS[k % len(HINGE_FRACTIONS)]
        for i, lim in enumerate(skeleton.limits):
            if isinstance(lim, Hinge):
                half = 0.5 * (lim.lo + f * (lim.hi - lim.lo))
                starts = starts.at[k, i].set(jnp.asarray((np.cos(half), *(np.sin(half) * np.asarray(lim.axis))), dtype))
    return starts


def best_of(res: IKResult, n: int, seeds: int) -> IKResult:
    """Per set, the seed kept from a flat ``(n * seeds)`` result: the first that converged,
    else the one of least worst position error.  ``iterations`` counts every seed's iterations."""
    split = jax.tree_util.tree_map(lambda a: a.reshape((n, seeds) + a.shape[1:]), res)
    worst = jnp.max(split.error, axis=-1)
    score = jnp.where(split.converged, jnp.arange(seeds) - seeds, worst)
    pick = jnp.argmin(score, axis=1)

    def take(a):
        return jnp.take_along_axis(a, pick.reshape((n, 1) + (1,) * (a.ndim - 2)), axis=1)[:, 0]

    out = jax.tree_util.tree_map(take, split)
    return IKResult(rotations=out.rotations, positions=out.positions, error=out.error,
                    iterations=jnp.sum(split.iterations, axis=1), converged=out.converged, reachable=out.reachable,
                    trace=out.trace, angle_error=out.angle_error, stationary=out.stationary)
