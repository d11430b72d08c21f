"""Additive CCD (Li et al. 2021, "Codimensional Incremental Potential Contact", Alg. 1).

A conservative time of impact for a pair of primitives moving linearly: the pair advances
by steps that cannot close more than 0.9 of its current distance (the relative
displacement is bounded by ``l_p``, the sum of each primitive's largest vertex
displacement after removing the mean), until the distance drops below ``s`` times the
start's.  Every time it returns is collision-free along the whole path before it.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax

from .._vec import length

#: ACCD's separation target ``s``: a step may close a pair to this fraction of its distance.
SEPARATION = 0.1
#: ACCD's iteration cap; a pair still advancing there returns the safe time it reached.
MAX_ITERS = 64


def reach(dx, split: int):
    """``(P,)`` ACCD's ``l_p``: a bound on how much a pair's distance can change over the
    motion ``dx (P, 4, 3)`` (each primitive's largest vertex displacement, the pair's mean
    displacement removed); vertices ``[:split]`` make the first primitive."""
    n = [length(v) for v in _relative(dx)]
    if split == 1:
        return n[0] + jnp.maximum(jnp.maximum(n[1], n[2]), n[3])
    return jnp.maximum(n[0], n[1]) + jnp.maximum(n[2], n[3])


def _relative(dx):
    """The four vertices' displacements ``(P, 3)`` less their mean, ``dx (P, 4, 3)``: written
    per vertex (XLA:CPU ran the mean over the axis of 4 as a library reduction, 10x slower)."""
    v = [dx[:, i] for i in range(4)]
    mean = 0.25 * (v[0] + v[1] + v[2] + v[3])
    return [u - mean for u in v]


def additive(x, dx, dist2, split: int, t_max=1.0):
    """``(P,)`` a safe fraction ``t <= t_max`` of the motion ``dx`` for each pair.

    Args:
      x: ``(P, 4, 3)`` the pairs' vertices (m).
      dx: ``(P, 4, 3)`` their displacements over the step (m).
      dist2: ``(v0, v1, v2, v3) -> (P,)`` squared distance (m^2).
      split: vertices ``[:split]`` make the first primitive (1: point–triangle, 2: edge–edge).
      t_max: ``()`` the fraction of ``dx`` that may be taken at most.
    """
    p = jnp.stack(_relative(dx), axis=1)
    lp = reach(dx, split)
    moving = lp > 0
    lps = jnp.where(moving, lp, 1.0)

    def dist(t):
        y = x + t[:, None, None] * p
        d2 = dist2(y[:, 0], y[:, 1], y[:, 2], y[:, 3])
        return jnp.sqrt(jnp.maximum(d2, 0.0))

    d0 = dist(jnp.zeros_like(lp))
    target = SEPARATION * d0
    t0 = jnp.zeros_like(lp)
    step0 = (1.0 - SEPARATION) * d0 / lps
    done0 = ~moving | (d0 <= 0)

    def body(c):
        t, step, done, k = c
        trial = t + step
        d = dist(trial)
        stop = (d < target) & (k > 0)  # the first step cannot close the pair below the target
        t_new = jnp.where(done | stop, t, trial)
        over = t_new >= t_max
        return t_new, 0.9 * d / lps, done | stop | over, k + 1

    t, _, _, _ = lax.while_loop(lambda c: (c[3] < MAX_ITERS) & ~jnp.all(c[2]), body, (t0, step0, done0, jnp.int32(0)))
    return jnp.where(moving, jnp.minimum(t, t_max), t_max)
