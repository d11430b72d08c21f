"""The extrapolated Newton start of ``rollout``: the velocities before a step."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._dataclass import pytree_dataclass


@pytree_dataclass
class History:
    """The velocities before a step that ``rollout``'s extrapolated start needs.

    Attributes:
      v_prev: ``(N, 3)`` ``v^{n-1}`` (m/s; ``v^0`` on the first step, which then starts from
        ``x^0 + h v^0``).
      d_prev: ``(N, 3)`` ``v^{n-1} - v^{n-2}`` (m/s), or ``None`` (linear extrapolation).
      count: ``()`` int32 steps taken (the constant-jerk term needs two).
    """

    v_prev: jax.Array
    d_prev: jax.Array | None = None
    count: jax.Array | None = None

    @staticmethod
    def first(v0, order: int) -> "History":
        if order < 2:
            return History(v0)
        return History(v0, jnp.zeros_like(v0), jnp.int32(0))

    def start(self, p) -> jax.Array:
        """``(N, 3)`` the deviation ``w`` of the extrapolated positions
        ``x^n + h (v^n + dv + [dv - d_prev])`` with ``dv = v^n - v^{n-1}``, without rounding
        ``x`` (the bracket with ``d_prev`` only, from the third step on)."""
        dv = p.v0 - self.v_prev
        if self.d_prev is not None:
            dv = dv + jnp.where(self.count >= 2, dv - self.d_prev, 0.0)
        return p.h * dv - p.h**2 * p.cloth.gravity

    def advance(self, v) -> "History":
        """The history for the step after one that started at velocity ``v (N, 3)``."""
        if self.d_prev is None:
            return History(v)
        return History(v, v - self.v_prev, self.count + 1)
