"""The extrapolated Newton start of ``rollout``: the velocities before a step."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..._dataclass import pytree_dataclass
from .._model import energy as en
from .._layout import spring_diff, spring_sum
from .._vec import dot

#: ``ImplicitEuler(extrapolate="auto")``: a step that converged within this many Newton
#: iterations marks the motion as smooth, and the next step starts from the constant-jerk
#: extrapolation with a first PCG solve aimed at the gradient test (one iteration is then
#: expected to meet it; ``_implicit.newton.newton``'s ``tight_first``; README, "Extrapolated start").
SMOOTH_NEWTON = 2


def acceleration(cloth, x, v, layout=None):
    """``(N, 3)`` ``a = F(x, v) / m`` (m/s^2; 0 on pins): springs by the radial form
    (``psi'(s) e``, summed at both ends without a scatter on a grid), gravity, and the
    along-spring damping ``d ((v_j - v_i) . e) e`` with ``e`` at ``x``.  A backward-Euler
    step that ends at ``(x, v)`` had ``v - h a`` as its first velocity."""
    d = spring_diff(cloth, x, layout)
    e, dpsi, _, _ = en.radial_parts(d, en._length(d) - cloth.rest_length, cloth.stiffness)
    f = dpsi[:, None] * e
    if cloth.damped:
        f = f + (cloth.damping * dot(spring_diff(cloth, v, layout), e))[:, None] * e
    a = cloth.gravity - spring_sum(cloth, f, layout=layout) / cloth.mass[:, None]
    return jnp.where(cloth.pinned[:, None], 0.0, a)


@pytree_dataclass
class History:
    """The velocities before a step that ``rollout``'s extrapolated start needs.

    Attributes:
      v_prev: ``(N, 3)`` ``v^{n-1}`` (m/s).
      d_prev: ``(N, 3)`` ``v^{n-1} - v^{n-2}`` (m/s), or ``None`` (linear extrapolation only).
      smooth: ``()`` bool, use the constant-jerk term (``extrapolate=2``: always;
        ``"auto"``: the last step converged within ``SMOOTH_NEWTON`` iterations), or ``None``.
    """

    v_prev: jax.Array
    d_prev: jax.Array | None = None
    smooth: jax.Array | None = None

    @staticmethod
    def before(cloth, x, v, h, mode, resume=None, layout=None) -> "History":
        """The history before a rollout's first step from ``(x, v)`` (``(N, 3)``);
        ``mode``: ``ImplicitEuler.extrapolate``; ``layout``: the scene's (``_layout``).

        ``resume``: the previous rollout's :class:`_implicit.resume.Resume` (its last
        ``T <= 3`` velocities and its last step's diagnostics), whose velocities are used
        where known, so that the rollout starts where the same
        rollout, one step longer, would have.  The velocities not known are those of the
        backward-Euler motion that ends at ``(x, v)``: ``v^{n-1} = v - h a(x, v)`` and
        ``v^{n-2} = v^{n-1} - h a(x - h v, v^{n-1})`` (:func:`acceleration`).  So a bare
        rollout starts its first step from the constant-acceleration extrapolation, and
        (``"auto"`` takes a bare state's motion as smooth) from the constant-jerk one: on
        a smoothly moving cloth one Newton iteration from the first step on, as in a long
        rollout, instead of three and two on the first two steps.  From rest (``a = g``
        on free particles) it is ``x^0 + h^2 g``."""
        known = 0 if resume is None else resume.v.shape[0]
        v_prev = resume.v[-2] if known >= 2 else v - h * acceleration(cloth, x, v, layout)
        if mode == 1:
            return History(v_prev)
        v_prev2 = resume.v[-3] if known >= 3 else v_prev - h * acceleration(cloth, x - h * v, v_prev, layout)
        if mode == 2 or resume is None:
            smooth = jnp.array(True)
        else:
            smooth = resume.converged & (resume.newton_iters <= SMOOTH_NEWTON)
        return History(v_prev, v_prev - v_prev2, smooth)

    @property
    def jerk(self) -> jax.Array | bool:
        """``()`` bool, the start includes the constant-jerk term."""
        return False if self.d_prev is None else self.smooth

    def start(self, p) -> jax.Array:
        """``(N, 3)`` the deviation ``w`` of the extrapolated positions
        ``x^n + h (v^n + dv + [dv - d_prev])`` with ``dv = v^n - v^{n-1}``, without rounding
        ``x`` (the bracket where :attr:`jerk`)."""
        return p.h * self.change(p.v0) - p.h**2 * p.cloth.gravity

    def change(self, v) -> jax.Array:
        """``(N, 3)`` the extrapolated velocity's change from ``v = v^n``: ``dv`` (and the
        jerk term ``dv - d_prev`` where :attr:`jerk`)."""
        dv = v - self.v_prev
        if self.d_prev is not None:
            dv = dv + jnp.where(self.jerk, dv - self.d_prev, 0.0)
        return dv

    def start_at(self, p, v) -> jax.Array:
        """:meth:`start` for a problem ``p`` that is not built on the step's own ``(x, v, h)``
        (BDF2's, ``_implicit.bdf2``): the positions whose velocity under ``p`` is the same
        extrapolated velocity ``v + dv``, ``w = p.h (v + dv - p.v0) - p.h^2 g`` (``start``
        where ``p`` is backward Euler's).  The extrapolated positions ``x + h (v + dv)``
        themselves took BDF2 two Newton iterations a step where this takes one (B 32x32, CG, float64)."""
        return p.h * (v + self.change(v) - p.v0) - p.h**2 * p.cloth.gravity

    def advance(self, v, info, mode) -> "History":
        """The history for the step after one that started at velocity ``v (N, 3)`` and
        ended with ``info`` (``StepInfo``)."""
        if self.d_prev is None:
            return History(v)
        smooth = self.smooth if mode == 2 else info.converged & (info.newton_iters <= SMOOTH_NEWTON)
        return History(v, v - self.v_prev, smooth)
