"""The extrapolated Newton start of ``rollout``: the velocities before a step."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._dataclass import pytree_dataclass

#: ``ImplicitEuler(extrapolate="auto")``: a step that converged within this many Newton
#: iterations marks the motion as smooth, and the next step starts from the constant-jerk
#: extrapolation with a first PCG solve aimed at the gradient test (one iteration is then
#: expected to meet it; ``_newton.newton``'s ``tight_first``; README, "Extrapolated start").
SMOOTH_NEWTON = 2


@pytree_dataclass
class History:
    """The velocities before a step that ``rollout``'s extrapolated start needs.

    Attributes:
      v_prev: ``(N, 3)`` ``v^{n-1}`` (m/s; ``v^0`` on the first step, which then starts from
        ``x^0 + h v^0``).
      d_prev: ``(N, 3)`` ``v^{n-1} - v^{n-2}`` (m/s), or ``None`` (linear extrapolation only).
      count: ``()`` int32 steps taken (the constant-jerk term needs two), or ``None``.
      smooth: ``()`` bool, use the constant-jerk term (``extrapolate=2``: always;
        ``"auto"``: the last step converged within ``SMOOTH_NEWTON`` iterations), or ``None``.
    """

    v_prev: jax.Array
    d_prev: jax.Array | None = None
    count: jax.Array | None = None
    smooth: jax.Array | None = None

    @staticmethod
    def first(v0, mode) -> "History":
        """The history before a rollout's first step; ``mode``: ``ImplicitEuler.extrapolate``."""
        if mode == 1:
            return History(v0)
        return History(v0, jnp.zeros_like(v0), jnp.int32(0), jnp.array(mode == 2))

    @staticmethod
    def after(v, converged, newton_iters, mode) -> "History":
        """The history after a rollout whose states had velocities ``v (T, N, 3)`` and whose
        last step ended with ``converged`` and ``newton_iters`` (``()``), so that the next
        rollout starts where the same rollout, one step longer, would have.  ``T = 1`` gives
        :meth:`first` (the step before is unknown); ``T = 2`` the linear extrapolation at
        once and the constant-jerk one a step later."""
        T = v.shape[0]
        if T == 1:
            return History.first(v[-1], mode)
        if mode == 1:
            return History(v[-2])
        d_prev = v[-2] - v[-3] if T >= 3 else jnp.zeros_like(v[-1])
        smooth = jnp.array(True) if mode == 2 else converged & (newton_iters <= SMOOTH_NEWTON)
        return History(v[-2], d_prev, jnp.int32(2 if T >= 3 else 1), smooth)

    @property
    def jerk(self) -> jax.Array | bool:
        """``()`` bool, the start includes the constant-jerk term."""
        return False if self.d_prev is None else (self.count >= 2) & self.smooth

    def start(self, p) -> jax.Array:
        """``(N, 3)`` the deviation ``w`` of the extrapolated positions
        ``x^n + h (v^n + dv + [dv - d_prev])`` with ``dv = v^n - v^{n-1}``, without rounding
        ``x`` (the bracket where :attr:`jerk`)."""
        dv = p.v0 - self.v_prev
        if self.d_prev is not None:
            dv = dv + jnp.where(self.jerk, dv - self.d_prev, 0.0)
        return p.h * dv - p.h**2 * p.cloth.gravity

    def advance(self, v, info, mode) -> "History":
        """The history for the step after one that started at velocity ``v (N, 3)`` and
        ended with ``info`` (``StepInfo``)."""
        if self.d_prev is None:
            return History(v)
        smooth = self.smooth if mode == 2 else info.converged & (info.newton_iters <= SMOOTH_NEWTON)
        return History(v, v - self.v_prev, self.count + 1, smooth)
