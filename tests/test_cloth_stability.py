import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import cloth as C
from _helpers import all_eqns, step_jaxpr, users_jit

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))
from cloth_stability import DTS, KS, sweep  # noqa: E402

IMPLICIT = C.ImplicitEuler(newton_iters=20, tol=1e-6)


def check_rows(rows):
    for r in rows:
        assert r["finite"] and r["stable"], r
        assert r["energy_not_above_initial"], r


def users_rollout(steps):
    """``C.rollout`` of ``steps`` with ``IMPLICIT``, compiled once (``k`` and ``dt`` are data) with
    XLA:CPU's default options: the sweeps run 16 rollouts each, run-time bound (half the time)."""
    run = users_jit(lambda c, s0, dt: C.rollout(c, s0, dt, steps, IMPLICIT))
    return lambda c, s0, dt, n, integrator: run(c, s0, jnp.asarray(dt, c.dtype))


@pytest.mark.slow
def test_stability_sweep_lab_cloth():
    """k in {1e2..1e7} x dt in {1/600..1/10}, 200 steps: finite, energy not above the start."""
    rows = sweep(C.lab_cloth(dtype=np.float64), 200, IMPLICIT, rollout=users_rollout(200))
    assert len(rows) == len(KS) * len(DTS)
    check_rows(rows)


@pytest.mark.slow
def test_stability_sweep_24x24_short():
    """The same sweep on a 24x24 grid, 20 steps each (200 steps: benchmarks/cloth_stability.py)."""
    rows = sweep(C.grid(23, 0.2, dtype=np.float64), 20, IMPLICIT, rollout=users_rollout(20))
    check_rows(rows)


@pytest.mark.parametrize("factor", [3.0, 0.01])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.slow
def test_stretched_and_crushed_start(factor, dtype):
    c = C.lab_cloth(dtype=dtype)
    centre = jnp.mean(c.rest, axis=0)
    x0 = centre + factor * (c.rest - centre)
    x0 = jnp.where(c.pinned[:, None], c.rest, x0)
    s0 = C.State(x0, jnp.zeros_like(x0))
    states, infos = C.rollout(c, s0, 1 / 60, 60, IMPLICIT)
    rep = C.energy_report(c, s0, states, infos)
    assert bool(rep.finite) and bool(rep.stable)
    assert float(rep.net_change) <= 0


@pytest.mark.slow
def test_all_pinned_no_pins_and_tiny_grid():
    c = C.grid(4, 0.2, pins=np.arange(25), dtype=np.float64)
    s, info = C.step(c, C.State.at_rest(c), 1 / 60, IMPLICIT)
    assert np.array_equal(np.asarray(s.x), np.asarray(c.rest)) and bool(info.stable)
    free = C.grid(4, 0.2, pins=[], dtype=np.float64)
    states, infos = C.rollout(free, C.State.at_rest(free), 1 / 60, 30, IMPLICIT)
    # no pins: the sheet falls as a rigid body under gravity (no spring is stretched)
    np.testing.assert_allclose(states.x[:, :, 1] - free.rest[:, 1], np.broadcast_to(states.x[:, :1, 1] - free.rest[0, 1], (30, 25)), atol=1e-9)
    assert bool(jnp.all(infos.stable))
    tiny = C.grid(1, 0.2, dtype=np.float64)
    assert tiny.num_particles == 4 and tiny.num_springs == 6
    states, infos = C.rollout(tiny, C.State.at_rest(tiny), 1 / 60, 30, IMPLICIT)
    assert bool(jnp.all(infos.stable)) and bool(jnp.all(jnp.isfinite(states.x)))


@pytest.mark.slow
def test_large_grid_with_cg():
    c = C.grid(127, 0.2, dtype=np.float32)
    assert c.num_particles == 128 * 128 and c.dtype == np.float32
    states, infos = C.rollout(c, C.State.at_rest(c), 1 / 60, 2, C.ImplicitEuler(linear_solver=C.CG()))
    assert bool(jnp.all(infos.stable)) and bool(jnp.all(jnp.isfinite(states.x)))
    assert int(infos.cg_iters[0]) > 0


# ---- what the compiled step contains ----

def largest_intermediate(jaxpr):
    return max(int(np.prod(v.aval.shape)) for e in all_eqns(jaxpr) for v in e.outvars if hasattr(v.aval, "shape"))


def test_cg_step_forms_no_dense_matrix():
    c = C.grid(31, 0.2)
    N = c.num_particles
    assert largest_intermediate(step_jaxpr(c, C.ImplicitEuler(linear_solver=C.CG()))) < (3 * N) ** 2
    # and the check can fail: the dense step does form one
    small = C.grid(7, 0.2)
    assert largest_intermediate(step_jaxpr(small, C.ImplicitEuler(linear_solver=C.Cholesky()))) >= (3 * small.num_particles) ** 2


def test_explicit_step_has_no_hessian_and_undamped_has_no_damping():
    c = C.lab_cloth()
    prims = {e.primitive.name for e in all_eqns(step_jaxpr(c, C.ExplicitEuler(substeps=4)))}
    assert "cholesky" not in prims and "while" not in prims
    assert largest_intermediate(step_jaxpr(c, C.ExplicitEuler(substeps=4))) < (3 * c.num_particles) ** 2
    undamped = C.grid(10, 0.2, damping=0.0)
    assert not undamped.damped and c.damped
    for integ in (C.ExplicitEuler(substeps=4), C.ImplicitEuler(linear_solver=C.CG())):
        n_damped = sum(1 for _ in all_eqns(step_jaxpr(c, integ)))
        n_undamped = sum(1 for _ in all_eqns(step_jaxpr(undamped, integ)))
        assert n_undamped < n_damped
    # the damping leaf of an undamped scene is not read by the compiled step
    leaves = jax.tree_util.tree_leaves((undamped, C.State.at_rest(undamped)))
    idx = [i for i, l in enumerate(leaves) if l is undamped.damping][0]
    jp = step_jaxpr(undamped, C.ImplicitEuler(linear_solver=C.CG()))
    var = jp.invars[idx]
    assert all(var not in e.invars for e in all_eqns(jp))
