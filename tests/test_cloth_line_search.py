"""The line search's rounding slack (``_implicit.line_search``): taken only where the
decrease the slope predicts is within it."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import cloth as C
from jaxsim.cloth._implicit import problem as pr
from jaxsim.cloth._implicit.line_search import line_search
from jaxsim.cloth._implicit.newton import newton
from jaxsim.cloth._implicit.setup import NewtonSetup

jax.config.update("jax_enable_x64", True)


def _overshoot(scale):
    """A lab cloth's minimiser ``w*``, the setup, and a direction ``e`` with
    ``e'He = scale * slack``, the slack being ``g``'s rounding allowance at ``w*``."""
    cloth = C.grid(3, 0.1, mass=1 / 16, stiffness=1e3, gravity=9.8, damping=0.0, dtype=np.float64)
    s = C.State.at_rest(cloth)
    p = pr.StepProblem.build(cloth, s.x, s.v, jnp.float64(1 / 30))
    integ = C.ImplicitEuler(linear_solver=C.Cholesky())
    sv = NewtonSetup(p, integ)
    w_star = newton(p, integ, 1e-12).iterate.w
    e = jax.random.normal(jax.random.PRNGKey(0), w_star.shape) * sv.free
    curv = jnp.vdot(e, jax.jvp(sv.grad, (w_star,), (e,))[1])
    slack = 8 * jnp.finfo(jnp.float64).eps * jnp.abs(sv.objective(w_star))
    return sv, w_star, e * jnp.sqrt(scale * slack / curv)


@pytest.mark.parametrize("scale, alpha", [(1.0, 0.5), (1 / 8, 1.0)])
def test_the_slack_applies_only_where_the_slope_predicts_less(scale, alpha):
    """From ``w* - e`` along ``2.5 e``: the full step lands at ``w* + 1.5 e``, and ``g``
    rises there by ``0.625 e'He``.  With ``e'He`` = the slack, that rise is within it while
    the slope predicts a decrease of 2.5 slacks: the step is not taken, and the half step
    lands at ``w* + 0.25 e``.  With ``e'He`` = 1/8 of the slack, the predicted decrease is
    within it too, and the full step is taken as before."""
    sv, w_star, e = _overshoot(scale)
    w0 = w_star - e
    at0 = sv.evaluate(w0)
    trial = line_search(sv, w0, at0.g, at0.grad, 2.5 * e)
    assert float(trial.alpha) == alpha and int(trial.backtracks) == int(np.log2(1 / alpha))
    np.testing.assert_allclose(w0 + trial.alpha * trial.dx, w_star + (2.5 * alpha - 1) * e,
                               rtol=0, atol=1e-14)
