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
from _helpers import (check_batch_equals_loop, check_friction_on_a_tilted_plane, check_rollout_grads,
                      check_substeps_converge_a_stiff_rollout)

jax.config.update("jax_enable_x64", True)

#: An undamped 6x6 cloth pinned at two corners, swinging under gravity.
SCENE = C.grid(5, 0.2, stiffness=100.0, gravity=9.8, damping=0.0, dtype=np.float64)
BDF = C.BDF2(linear_solver=C.Cholesky())
BE = C.ImplicitEuler(linear_solver=C.Cholesky())
BDF2_DEFAULT = C.BDF2()


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
    check_substeps_converge_a_stiff_rollout(BDF, newton_iters=4, whole=1)


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


def test_resumed_bdf2_rollouts_equal_one_rollout():
    """``resume`` carries BDF2's memory: 3 + 3 steps are the steps of one 6-step rollout
    (without it the resumed chunk starts with a backward-Euler step); in a batch too."""
    s0 = C.State.at_rest(SCENE)
    whole, _ = C.rollout(SCENE, s0, 1 / 30, 6, BDF)
    a, ia = C.rollout(SCENE, s0, 1 / 30, 3, BDF)
    nxt = C.State(a.x[-1], a.v[-1])
    b, ib = C.rollout(SCENE, nxt, 1 / 30, 3, BDF, resume=(a, ia))
    np.testing.assert_allclose(b.x, whole.x[3:], atol=1e-12)
    np.testing.assert_allclose(b.v, whole.v[3:], atol=1e-10)
    bare, _ = C.rollout(SCENE, nxt, 1 / 30, 3, BDF)
    assert float(jnp.max(jnp.abs(bare.x - whole.x[3:]))) > 1e-4
    scenes = C.stack_scenes([SCENE, C.replace(SCENE, stiffness=SCENE.stiffness * 2.0)])
    wb, _ = C.batch_rollout(scenes, s0, 1 / 30, 6, BDF)
    ab, iab = C.batch_rollout(scenes, s0, 1 / 30, 3, BDF)
    bb, _ = C.batch_rollout(scenes, C.State(ab.x[:, -1], ab.v[:, -1]), 1 / 30, 3, BDF, resume=(ab, iab))
    np.testing.assert_allclose(bb.x, wb.x[:, 3:], atol=1e-12)
    with pytest.raises(ValueError, match="positions of shape"):
        C.rollout(SCENE, nxt, 1 / 30, 3, BDF, resume=(C.State(a.x[:2], a.v), ia))


def test_a_resume_after_substeps_starts_with_backward_euler():
    """A last step taken in substeps remembers its last substep, which ``states`` does not
    hold: the resumed rollout's first step is then backward Euler's."""
    stiff = C.grid(5, 0.2, mass=1 / 36, stiffness=1e4, gravity=9.8, damping=0.0, dtype=np.float64)
    integ = dataclasses.replace(BDF, newton_iters=4, extrapolate=0, max_substep_depth=3, rtol=1e-12)
    states, infos = C.rollout(stiff, C.State.at_rest(stiff), 1 / 30, 8, integ)
    subs = np.asarray(infos.substeps)
    k = int(np.flatnonzero(subs > 1)[0])  # chunk ends on a substepped step
    chunk = jax.tree_util.tree_map(lambda t: t[: k + 1], (states, infos))
    nxt = C.State(states.x[k], states.v[k])
    b, ib = C.rollout(stiff, nxt, 1 / 30, 8, integ, resume=chunk)
    # no previous state (a backward-Euler first substep), from the substeps' memory that
    # ``resume`` carries on (``StepInfo.memory``)
    memory = jax.tree_util.tree_map(lambda m: m[k], infos.memory)
    first, info, _ = _step._step(stiff, layout_of(stiff.springs, stiff.rest), nxt, jnp.float64(1 / 30), integ,
                                 before=Before.none(nxt.x, nxt.v), memory=memory)
    assert bool(ib.converged[0]) and bool(info.converged) and int(ib.substeps[0]) == int(info.substeps)
    np.testing.assert_allclose(b.x[0], first.x, atol=1e-9)


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
    check_batch_equals_loop(SCENE, BDF, steps=4)


def test_gradients_through_a_bdf2_rollout():
    check_rollout_grads(SCENE, BDF, steps=3)


def test_bad_inputs():
    s0 = C.State.at_rest(SCENE)
    with pytest.raises(ValueError, match="previous= is BDF2's"):
        C.step(SCENE, s0, 1 / 30, BE, previous=s0)
    with pytest.raises(TypeError, match="previous must be a jaxsim.cloth.State"):
        C.step(SCENE, s0, 1 / 30, BDF, previous=(s0.x, s0.v))
    with pytest.raises(ValueError, match="previous.x"):
        C.step(SCENE, s0, 1 / 30, BDF, previous=C.State(s0.x[:3], s0.v))
    with pytest.raises(ValueError, match="colliders need ImplicitEuler"):
        C.rollout(DRAPE(np.float64), C.State.at_rest(DRAPE(np.float64)), 1 / 30, 2, C.ExplicitEuler())


# ---- with colliders ----

def DRAPE(dtype, k=1e5, mu=0.2):
    """A 4x4 cloth of 0.16 kg dropped onto a floor, a sphere and a capsule (with friction)."""
    cols = (C.Plane(np.array([0.0, 1.0, 0.0]), 0.0, friction=mu), C.Sphere(np.array([0.0, 0.5, 0.0]), 0.3, friction=mu),
            C.Capsule(np.array([-1.0, 0.2, 0.6]), np.array([1.0, 0.2, 0.6]), 0.15, friction=mu))
    return C.grid(3, 0.1, origin=(-0.15, 1.0, -0.15), mass=0.01, stiffness=k, damping=0.01, gravity=9.8, pins=[],
                  dtype=dtype, colliders=cols)


def _distance(colliders, x):
    x = jnp.asarray(np.asarray(x, np.float64).reshape(-1, 3))
    return min(float(jnp.min(c.distance(x))) for c in colliders)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_bdf2_drapes_onto_colliders(dtype):
    """IPC contact under BDF2: every step converges, nothing enters a collider, no energy
    is gained, and the cloth comes to rest on them, although BDF2's shifted base
    ``x^n + b (x^n - x^{n-1})`` lies inside one on many steps (Newton starts from ``x^n``)."""
    c = DRAPE(dtype)
    s0 = C.State.at_rest(c)
    for dt in (1 / 30, 1 / 240):  # data, so one compiled rollout
        states, infos = C.rollout(c, s0, dt, 100, BDF2_DEFAULT)
        assert bool(jnp.all(infos.converged)), (dt, np.asarray(infos.converged).mean())
        x = np.asarray(states.x, np.float64)
        assert _distance(c.colliders, x) >= 0.0, dt
        base = x[1:] + (x[1:] - x[:-1]) / 3.0  # b = 1/3 at equal steps
        assert _distance(c.colliders, base) < -1e-3, dt  # the case that needs the feasible start
        e = jax.vmap(lambda xx, vv: C.total_energy(c, xx, vv))(states.x, states.v)
        e0 = float(C.total_energy(c, s0.x, s0.v))
        assert float(jnp.max(e)) <= e0 + 1e-6 * abs(e0), (float(jnp.max(e)), e0)
    top = x[-1, :, 1]
    assert top.min() > 0.0 and top.max() < 1.0


def test_bdf2_friction_holds_below_atan_mu_and_slides_above():
    for theta in (15.0, 40.0):
        check_friction_on_a_tilted_plane(BDF2_DEFAULT, theta)


def test_a_collider_out_of_reach_changes_no_bdf2_step():
    """A floor 10 m below: the contact terms are all zero, so the rollout is the one
    without colliders up to Newton's tolerance (it starts from ``x^n`` instead of the
    extrapolation)."""
    integ = dataclasses.replace(BDF, rtol=1e-13)
    far = C.replace(SCENE, colliders=(C.Plane(np.array([0.0, 1.0, 0.0]), -10.0),))
    s0 = C.State.at_rest(SCENE)
    a, ia = C.rollout(far, s0, 1 / 30, 15, integ)
    b, ib = C.rollout(SCENE, s0, 1 / 30, 15, integ)
    assert bool(jnp.all(ia.converged)) and bool(jnp.all(ib.converged))
    np.testing.assert_allclose(a.x, b.x, atol=1e-10)
    np.testing.assert_allclose(a.v, b.v, atol=1e-8)
    # and with the shifted problem's contact terms: not backward Euler's
    be, _ = C.rollout(far, s0, 1 / 30, 15, dataclasses.replace(BE, rtol=1e-13))
    assert float(jnp.max(jnp.abs(be.x - a.x))) > 1e-3


@pytest.mark.slow
def test_gradients_through_bdf2_contact():
    """The implicit derivative of BDF2 steps with the barrier and friction: a cloth resting
    on a sphere, d(positions after two steps)/d(sphere centre, stiffness)."""
    c = C.grid(3, 0.1, origin=(-0.15, 0.85, -0.15), mass=0.01, stiffness=1e3, damping=0.01, gravity=9.8, pins=[],
               dtype=np.float64, colliders=(C.Sphere(np.array([0.0, 0.5, 0.0]), 0.3, friction=0.3),))
    s0 = C.State.at_rest(c)
    for _ in range(10):  # drape (the compiled rollout of the gradient below)
        states, _ = C.rollout(c, s0, 1 / 30, 2, BDF)
        s0 = C.State(states.x[-1], states.v[-1])
    assert _distance(c.colliders, s0.x) < float(c.contact_gap)  # in contact
    weights = jnp.arange(1.0, 1.0 + 3 * c.num_particles).reshape(-1, 3)

    def final_x(center, k):
        sc = C.replace(c, colliders=(C.Sphere(center, 0.3, 0.3),), stiffness=1e3 * k * jnp.ones(c.num_springs))
        out, info = C.rollout(sc, s0, 1 / 30, 2, BDF)
        return jnp.sum(out.x[-1] * weights)

    check_grads(final_x, (jnp.asarray([0.0, 0.5, 0.0]), jnp.asarray(1.0)), order=1, modes=("rev",), eps=1e-6)
