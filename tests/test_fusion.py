"""``jaxsim._fusion.materialized``: same values, NaN kept, and a buffer XLA cannot fuse away."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxsim import _fusion
from jaxsim import cloth as C
from jaxsim.cloth._implicit import problem as pr


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_values_unchanged_jit_and_eager(dtype):
    x = np.random.default_rng(0).standard_normal((7, 3)).astype(dtype)
    x[2, 1], x[4, 0] = np.inf, -np.inf
    for f in (_fusion.materialized, jax.jit(_fusion.materialized)):
        y = f(jnp.asarray(x))
        assert y.dtype == dtype and y.shape == x.shape
        np.testing.assert_array_equal(np.asarray(y), x)


def test_nan_is_kept():
    x = np.arange(6.0).reshape(2, 3)
    x[1, 2] = np.nan  # a NaN elsewhere stays where it is
    np.testing.assert_array_equal(np.asarray(_fusion.materialized(jnp.asarray(x))), x)
    x[0, 0] = np.nan  # a NaN first spreads: never a finite result from a NaN input
    assert np.all(np.isnan(np.asarray(_fusion.materialized(jnp.asarray(x)))))


def test_empty_and_scalar():
    assert _fusion.materialized(jnp.zeros((0, 3))).shape == (0, 3)
    assert float(_fusion.materialized(jnp.asarray(2.5))) == 2.5


def test_vmap_and_grad():
    x = jnp.asarray(np.random.default_rng(1).standard_normal((4, 5)))
    x = x.at[1, 0].set(jnp.nan)  # one batch row starts with NaN
    y = jax.vmap(_fusion.materialized)(x)
    assert np.all(np.isnan(np.asarray(y[1])))
    np.testing.assert_array_equal(np.asarray(y)[[0, 2, 3]], np.asarray(x)[[0, 2, 3]])
    z = jnp.asarray(np.random.default_rng(2).standard_normal(5))
    check_grads(lambda v: jnp.sum(jnp.sin(_fusion.materialized(v * v))), (z,), order=2, modes=("fwd", "rev"))


def test_the_compiled_step_keeps_the_buffers():
    """The point of the helper: the compiled gradient holds a conditional per use (XLA
    did not fold it away, as it does an optimisation barrier on CPU); with the helper off
    it holds none."""
    c = C.grid(7, 0.1)
    s = C.State.at_rest(c)
    p = pr.StepProblem.build(c, s.x, s.v, jnp.asarray(1 / 60))

    def conditionals():  # a new function each time: traced afresh under the current setting
        def grad(w):
            return pr.gradient(w, p, pr.spring_terms(w, p))

        return jax.jit(grad).lower(p.start).compile().as_text().count(" conditional(")

    assert conditionals() >= 4  # the spring changes, directions, psi' and forces
    try:
        _fusion.ENABLED = False
        assert conditionals() == 0
    finally:
        _fusion.ENABLED = True
