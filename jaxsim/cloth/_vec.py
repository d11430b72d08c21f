"""Vector helpers shared by the springs and the colliders: NaN-free lengths and their increments."""

from __future__ import annotations

import jax.numpy as jnp

from .._dtype import tiny


def length(v):
    """``|v|`` over the last axis, with a finite gradient at ``v = 0`` (a zero-length spring)."""
    s = jnp.sum(v * v, axis=-1)
    ok = ~(s <= tiny(v.dtype) ** 2)
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, s, 1.0)), 0.0)


def stretch_increment(d0, l0, dd):
    """``|d0 + dd| - |d0|`` without cancellation, for small ``dd`` (m).

    Written as ``(2 d0.dd + dd.dd) / (|d0 + dd| + |d0|)``, so its relative precision is
    that of ``dd`` and not that of ``|d0|``: the implicit step's unknown is the
    displacement, and float32 can then resolve motions far below ``eps * |x|``.

    Args:
      d0: ``(..., 3)`` spring vectors at the start of the step.
      l0: ``(...)`` their lengths ``|d0|``.
      dd: ``(..., 3)`` change of the spring vectors.
    """
    l = length(d0 + dd)
    den = l + l0
    ok = den > tiny(den.dtype)
    num = jnp.sum((2.0 * d0 + dd) * dd, axis=-1)
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), l - l0)
