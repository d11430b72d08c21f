"""BDF2 (``cloth.BDF2``): its equations checked from the forces, second order against
backward Euler's first, one step by hand against a rollout, substeps, vmap, gradients,
and its bad inputs."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxsim import cloth as C
from jaxsim.cloth import _step
from jaxsim.cloth._implicit.bdf2 import MAX_RATIO, Before
from jaxsim.cloth._layout import layout_of

jax.config.update("jax_enable_x64", True)

#: An undamped 6x6 cloth pinned at two corners, swinging under gravity.
SCENE = C.grid(5, 0.2, stiffness=100.0, gravity=9.8, damping=0.0, dtype=np.float64)
BDF = C.BDF2(linear_solver=C.Cholesky())
BE = C.ImplicitEuler(linear_solver=C.Cholesky())


def _end(integ, dt, t_end=0.5):
    """Positions at ``t_end`` by steps by hand (one compiled step whatever ``dt``)."""
    s, prev = C.State.at_rest(SCENE), None
    for _ in range(int(round(t_end / dt))):
        new, info = C.step(SCENE, s, dt, integ, previous=prev)
        assert bool(info.converged)
        s, prev = new, (s if integ is BDF else None)
    return np.asarray(s.x)


@pytest.fixture(scope="module")
def reference():
    return _end(BDF, 1 / 1920)


def test_bdf2_is_second_order_where_backward_euler_is_first(reference):
    err = {name: [np.abs(_end(integ, dt) - reference).max() for dt in (1 / 30, 1 / 60, 1 / 120)]
           for name, integ in (("be", BE), ("bdf2", BDF))}
    be, bdf = np.array(err["be"]), np.array(err["bdf2"])
    assert np.all((be[:-1] / be[1:] > 1.7) & (be[:-1] / be[1:] < 2.3)), be
    assert np.all(bdf[:-1] / bdf[1:] > 2.8), bdf
    assert np.all(bdf < 0.3 * be), (bdf, be)


def _bdf2_step(state, h, before):
    """One compiled step with BDF2's memory ``before`` (``_implicit.bdf2.Before``)."""
    layout = layout_of(SCENE.springs, SCENE.rest)
    new, info, _ = _step._step(SCENE, layout, state, jnp.asarray(h), BDF, before=before)
    assert bool(info.converged)
    return new


@pytest.mark.parametrize("ratio", [1.0, 0.5, 2.0, 2.5])
def test_each_step_solves_the_variable_step_bdf2_equations(ratio):
    """From the forces, with nothing of the solver: a step of ``h`` after one of
    ``h / ratio`` solves ``y1 - a y0 + b y_ = beta h f(y1)`` with Grigorieff's
    coefficients (``ratio`` 2.5 > ``MAX_RATIO``: backward Euler)."""
    h_prev, h = 1 / 30, ratio / 30
    s_ = C.State.at_rest(SCENE)
    s0, _ = C.step(SCENE, s_, h_prev, BE)
    s1 = _bdf2_step(s0, h, Before(s_.x, s_.v, jnp.asarray(h_prev)))
    w = ratio if ratio <= MAX_RATIO else 0.0
    a, b, beta = (1 + w) ** 2 / (1 + 2 * w), w * w / (1 + 2 * w), (1 + w) / (1 + 2 * w)
    x_, v_, x0, v0, x1, v1 = (np.asarray(t) for t in (s_.x, s_.v, s0.x, s0.v, s1.x, s1.v))
    m = np.asarray(SCENE.mass)[:, None]
    f = np.asarray(C.forces(SCENE, s1.x))
    rx = x1 - a * x0 + b * x_ - beta * h * v1
    rv = m * (v1 - a * v0 + b * v_) - beta * h * f
    free = ~np.asarray(SCENE.pinned)
    assert np.abs(rx[free]).max() < 1e-12
    assert np.abs(rv[free]).max() < 1e-8 * np.abs(beta * h * f[free]).max()
    np.testing.assert_array_equal(x1[~free], x0[~free])
    if ratio > MAX_RATIO:  # and that is the backward-Euler step
        be, _ = C.step(SCENE, s0, h, BE)
        np.testing.assert_allclose(x1, be.x, atol=1e-12)


def test_substeps_converge_a_stiff_bdf2_rollout():
    """Adaptive substeps serve BDF2 as they serve backward Euler: a stiff scene that four
    Newton iterations do not converge (``test_cloth_substeps.SCENE``) converges in halves
    and quarters."""
    stiff = C.grid(5, 0.2, mass=1 / 36, stiffness=1e4, gravity=9.8, damping=0.0, dtype=np.float64)
    integ = dataclasses.replace(BDF, newton_iters=4, extrapolate=0, max_substep_depth=3)
    _, infos = C.rollout(stiff, C.State.at_rest(stiff), 1 / 30, 8, integ)
    assert bool(jnp.all(infos.converged)) and int(jnp.max(infos.substeps)) > 1
    _, plain = C.rollout(stiff, C.State.at_rest(stiff), 1 / 30, 8, dataclasses.replace(integ, max_substep_depth=0))
    assert not bool(jnp.all(plain.converged))
    assert np.asarray(plain.substeps).tolist() == [1] * 8


def test_step_with_previous_equals_the_rollout():
    states, _ = C.rollout(SCENE, C.State.at_rest(SCENE), 1 / 30, 3, BDF)
    s1 = C.State(states.x[0], states.v[0])
    s2, _ = C.step(SCENE, s1, 1 / 30, BDF, previous=C.State.at_rest(SCENE))
    s3, _ = C.step(SCENE, s2, 1 / 30, BDF, previous=s1)
    np.testing.assert_allclose(s2.x, states.x[1], atol=1e-11)
    np.testing.assert_allclose(s3.x, states.x[2], atol=1e-11)
    np.testing.assert_allclose(s3.v, states.v[2], atol=1e-9)
    first, _ = C.step(SCENE, C.State.at_rest(SCENE), 1 / 30, BDF)  # no previous: backward Euler
    be, _ = C.step(SCENE, C.State.at_rest(SCENE), 1 / 30, BE)
    np.testing.assert_allclose(first.x, be.x, atol=1e-12)


def test_bdf2_keeps_the_energy_backward_euler_damps():
    """Undamped swing, one second at 1/30 s: backward Euler's numerical damping takes
    much more of the energy than BDF2's."""
    scene = C.replace(SCENE, pinned=jnp.zeros(36, bool).at[0].set(True))
    e = {}
    for name, integ in (("be", BE), ("bdf2", BDF)):
        s0 = C.State.at_rest(scene)
        states, infos = C.rollout(scene, s0, 1 / 30, 30, integ)
        assert bool(jnp.all(infos.converged))
        tot = jax.vmap(lambda x, v: C.total_energy(scene, x, v))(states.x, states.v)
        e[name] = float(jnp.min(tot) - C.total_energy(scene, s0.x, s0.v))
    assert e["bdf2"] < 0 and e["be"] < 0
    assert abs(e["bdf2"]) < 0.5 * abs(e["be"]), e


def test_batch_rollout_equals_a_loop_of_rollouts():
    scenes = [C.replace(SCENE, stiffness=SCENE.stiffness * k) for k in (1.0, 2.0)]
    batch = C.stack_scenes(scenes)
    s0 = C.State.at_rest(SCENE)
    states, infos = C.batch_rollout(batch, s0, 1 / 30, 4, BDF)
    for i, sc in enumerate(scenes):
        one, _ = C.rollout(sc, s0, 1 / 30, 4, BDF)
        np.testing.assert_allclose(states.x[i], one.x, atol=1e-10)


def test_gradients_through_a_bdf2_rollout():
    s0 = C.State.at_rest(SCENE)

    def loss(k, v0):
        sc = C.replace(SCENE, stiffness=SCENE.stiffness * k)
        states, _ = C.rollout(sc, C.State(s0.x, v0), 1 / 30, 3, BDF)
        return jnp.sum(states.x[-1, :, 1] ** 2) + jnp.sum(states.v[-1] ** 2)

    v0 = jnp.zeros_like(s0.x).at[:, 2].set(0.1)
    check_grads(loss, (jnp.asarray(1.0), v0), order=1, modes=("rev",), atol=1e-5, rtol=1e-5)


def test_bad_inputs():
    s0 = C.State.at_rest(SCENE)
    with pytest.raises(ValueError, match="previous= is BDF2's"):
        C.step(SCENE, s0, 1 / 30, BE, previous=s0)
    with pytest.raises(TypeError, match="previous must be a jaxsim.cloth.State"):
        C.step(SCENE, s0, 1 / 30, BDF, previous=(s0.x, s0.v))
    with pytest.raises(ValueError, match="previous.x"):
        C.step(SCENE, s0, 1 / 30, BDF, previous=C.State(s0.x[:3], s0.v))
    with_floor = C.replace(SCENE, colliders=(C.Plane(normal=(0.0, 1.0, 0.0), offset=0.0),))
    with pytest.raises(ValueError, match="BDF2 does not support colliders"):
        C.rollout(with_floor, C.State.at_rest(with_floor), 1 / 30, 2, BDF)
