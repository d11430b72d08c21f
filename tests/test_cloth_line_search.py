"""The line search within ``g``'s rounding: Hager & Zhang's approximate Armijo condition
(``_implicit.line_search``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import cloth as C
from jaxsim.cloth._implicit import problem as pr
from jaxsim.cloth._implicit.line_search import line_search
from jaxsim.cloth._implicit.newton import newton
from jaxsim.cloth._implicit.setup import NewtonSetup

jax.config.update("jax_enable_x64", True)


def test_an_overshoot_that_g_cannot_resolve_is_not_taken():
    """From ``w* - e`` along ``8 e`` (the minimum at ``a = 1/8``), with ``e`` so small that
    the rise at ``a = 1`` (``24 e'He``) is half of ``g``'s rounding slack: the values alone
    would take the full step uphill; the slopes at the trials turn it down until
    ``a = 1/8``."""
    cloth = C.grid(3, 0.1, mass=1 / 16, stiffness=1e3, gravity=9.8, damping=0.0, dtype=np.float64)
    s = C.State.at_rest(cloth)
    p = pr.StepProblem.build(cloth, s.x, s.v, jnp.float64(1 / 30))
    integ = C.ImplicitEuler(linear_solver=C.Cholesky())
    sv = NewtonSetup(p, integ)
    w_star = newton(p, integ, 1e-12).iterate.w
    e = jax.random.normal(jax.random.PRNGKey(0), w_star.shape) * sv.free
    curv = jnp.vdot(e, jax.jvp(sv.grad, (w_star,), (e,))[1])
    slack = 8 * jnp.finfo(jnp.float64).eps * jnp.abs(sv.objective(w_star))
    e = e * jnp.sqrt(slack / 48 / curv)
    w0 = w_star - e
    at0 = sv.evaluate(w0)
    trial = line_search(sv, w0, at0.g, at0.grad, 8 * e)
    assert float(trial.alpha) == 0.125 and int(trial.backtracks) == 3
    np.testing.assert_allclose(w0 + trial.alpha * trial.dx, w_star, rtol=0, atol=1e-12)
