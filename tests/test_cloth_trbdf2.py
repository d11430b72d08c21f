"""TR-BDF2 (``cloth.TRBDF2``): one step against its two stages solved by SciPy from the
forces, second order, the memory a rollout carries, substeps, contact, vmap, gradients,
and its bad inputs."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import optimize

from jaxsim import cloth as C
from jaxsim.cloth import _step
from jaxsim.cloth._implicit import trbdf2
from jaxsim.cloth._implicit.trbdf2 import GAMMA
from jaxsim.cloth._layout import layout_of
from _helpers import (check_batch_equals_loop, check_friction_on_a_tilted_plane, check_rollout_grads,
                      check_substeps_converge_a_stiff_rollout)

jax.config.update("jax_enable_x64", True)

#: An undamped 6x6 cloth pinned at two corners, swinging under gravity (``test_cloth_bdf2``'s).
SCENE = C.grid(5, 0.2, stiffness=100.0, gravity=9.8, damping=0.0, dtype=np.float64)
TR = C.TRBDF2(linear_solver=C.Cholesky())
BE = C.ImplicitEuler(linear_solver=C.Cholesky())
BDF = C.BDF2(linear_solver=C.Cholesky())


def _by_hand(integ, dt, t_end=0.3):
    """Positions at ``t_end`` by calls of the compiled step (one compiled step whatever
    ``dt``), TR-BDF2's memory carried as ``rollout`` carries it."""
    s = C.State.at_rest(SCENE)
    layout = layout_of(SCENE.springs, SCENE.rest)
    mem = trbdf2.first(SCENE, s.x, s.v, layout) if isinstance(integ, C.TRBDF2) else None
    for _ in range(int(round(t_end / dt))):
        s, info, mem = _step._step(SCENE, layout, s, jnp.asarray(dt), integ, before=mem)
        assert bool(info.converged)
    return np.asarray(s.x)


def test_gamma_is_two_minus_root_two():
    assert GAMMA == pytest.approx(2.0 - math.sqrt(2.0), abs=1e-15)


def test_a_step_solves_the_trapezoidal_and_bdf2_stages():
    """From the forces, with nothing of the solver: SciPy solves the trapezoidal stage over
    ``gamma h`` from ``(x^n, v^n)`` with ``a^n = F(x^n) / m``, then variable-step BDF2 over
    ``(1 - gamma) h`` through ``x^n`` and ``x^g``; the step lands on the same state."""
    h = 1 / 30
    s0, _ = C.step(SCENE, C.State.at_rest(SCENE), 0.1, BE)  # a moving, stretched state
    s1, info = C.step(SCENE, s0, h, dataclasses.replace(TR, rtol=1e-13))
    assert bool(info.converged) and int(info.substeps) == 2
    free = ~np.asarray(SCENE.pinned)
    m = np.asarray(SCENE.mass)[:, None]
    x0, v0 = np.asarray(s0.x), np.asarray(s0.v)
    forces = jax.jit(lambda x: C.forces(SCENE, x))
    force = lambda x: np.asarray(forces(jnp.asarray(x)))  # noqa: E731

    def solve(residual, guess):
        def r(q):
            x = guess.copy()
            x[free] = q.reshape(-1, 3)
            return residual(x)[free].ravel()
        sol = optimize.root(r, guess[free].ravel(), tol=1e-13)
        assert np.abs(sol.fun).max() < 1e-10, np.abs(sol.fun).max()
        out = guess.copy()
        out[free] = sol.x.reshape(-1, 3)
        return out

    h1, h2 = GAMMA * h, (1 - GAMMA) * h
    a0 = force(x0) / m
    vg_of = lambda x: 2.0 * (x - x0) / h1 - v0  # noqa: E731  (trapezoidal positions)
    xg = solve(lambda x: m * (vg_of(x) - v0) - 0.5 * h1 * (m * a0 + force(x)), x0 + h1 * v0)
    vg = vg_of(xg)
    w = h2 / h1
    a, b, beta = (1 + w) ** 2 / (1 + 2 * w), w * w / (1 + 2 * w), (1 + w) / (1 + 2 * w)
    v1_of = lambda x: (x - a * xg + b * x0) / (beta * h2)  # noqa: E731
    x1 = solve(lambda x: m * (v1_of(x) - a * vg + b * v0) - beta * h2 * force(x), xg + h2 * vg)
    np.testing.assert_allclose(np.asarray(s1.x), x1, atol=1e-11)
    np.testing.assert_allclose(np.asarray(s1.v)[free], v1_of(x1)[free], atol=1e-8)
    np.testing.assert_array_equal(np.asarray(s1.x)[~free], x0[~free])


def test_tr_bdf2_is_second_order_with_a_fifth_of_bdf2s_error():
    ref = _by_hand(TR, 1 / 960)
    tr = np.array([np.abs(_by_hand(TR, dt) - ref).max() for dt in (1 / 30, 1 / 60, 1 / 120)])
    assert np.all(tr[:-1] / tr[1:] > 3.3), tr
    be = np.abs(_by_hand(BE, 1 / 30) - ref).max()
    states, _ = C.rollout(SCENE, C.State.at_rest(SCENE), 1 / 30, 9, BDF)
    bdf = np.abs(np.asarray(states.x[-1]) - ref).max()
    assert tr[0] < 0.1 * be and tr[0] < 0.3 * bdf, (tr, be, bdf)


def test_a_rollout_carries_the_solved_acceleration():
    """A rollout's trapezoidal stage reads the acceleration the step before solved for;
    undamped and without contact that is ``F(x) / m`` at the step's end to Newton's
    tolerance, which is what a step by hand computes: both agree."""
    integ = dataclasses.replace(TR, rtol=1e-13)
    s = C.State.at_rest(SCENE)
    states, infos = C.rollout(SCENE, s, 1 / 30, 4, integ)
    assert bool(jnp.all(infos.converged)) and np.asarray(infos.substeps).tolist() == [2] * 4
    for t in range(4):
        s, _ = C.step(SCENE, s, 1 / 30, integ)
        np.testing.assert_allclose(np.asarray(s.x), np.asarray(states.x[t]), atol=1e-10)
    # resumed: the forces at the state again, so the same steps
    b, _ = C.rollout(SCENE, C.State(states.x[1], states.v[1]), 1 / 30, 2, integ,
                     resume=jax.tree_util.tree_map(lambda a: a[:2], (states, infos)))
    np.testing.assert_allclose(b.x, states.x[2:], atol=1e-10)


def test_substeps_converge_a_stiff_tr_bdf2_rollout():
    check_substeps_converge_a_stiff_rollout(TR, newton_iters=3, whole=2)


def test_batch_rollout_equals_a_loop_of_rollouts():
    check_batch_equals_loop(SCENE, TR, steps=2)


def test_gradients_through_a_tr_bdf2_rollout():
    check_rollout_grads(SCENE, TR, steps=2)


def test_moving_pins_end_each_step_exactly_on_their_path():
    """Pins move on straight lines through both stages and end each step exactly on the
    path (the first stage ends at ``gamma`` of the way)."""
    rows = np.flatnonzero(np.asarray(SCENE.pinned))
    p0 = np.asarray(SCENE.rest)[rows]
    path = np.stack([p0 + np.array([0.05 * (t + 1), 0.0, 0.0]) for t in range(4)])
    states, infos = C.rollout(SCENE, C.State.at_rest(SCENE), 1 / 30, 4, TR, pins=path)
    assert bool(jnp.all(infos.converged))
    np.testing.assert_array_equal(np.asarray(states.x)[:, rows], path)


def _drape(dtype):
    """A 4x4 cloth of 0.16 kg dropped onto a floor and a sphere, with friction."""
    cols = (C.Plane(np.array([0.0, 1.0, 0.0]), 0.0, friction=0.2), C.Sphere(np.array([0.0, 0.5, 0.0]), 0.3, friction=0.2))
    return C.grid(3, 0.1, origin=(-0.15, 1.0, -0.15), mass=0.01, stiffness=1e4, damping=0.01, gravity=9.8, pins=[],
                  dtype=dtype, colliders=cols)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_tr_bdf2_drapes_onto_colliders(dtype):
    """IPC contact under TR-BDF2: every step converges, nothing enters a collider, no
    energy is gained, and the cloth lies on the sphere (its corners, hanging over the
    edge as pendulums, keep swinging: TR-BDF2 does not damp them as backward Euler does)."""
    c = _drape(dtype)
    s0 = C.State.at_rest(c)
    states, infos = C.rollout(c, s0, 1 / 30, 40, C.TRBDF2())
    assert bool(jnp.all(infos.converged)), np.asarray(infos.converged).mean()
    x = np.asarray(states.x, np.float64)
    assert min(float(jnp.min(col.distance(jnp.asarray(x.reshape(-1, 3))))) for col in c.colliders) >= 0.0
    e = jax.vmap(lambda xx, vv: C.total_energy(c, xx, vv))(states.x, states.v)
    e0 = float(C.total_energy(c, s0.x, s0.v))
    assert float(jnp.max(e)) <= e0 + 1e-5 * abs(e0), (float(jnp.max(e)), e0)
    y = x[-1, :, 1]
    assert y.min() > 0.7 and y.max() < 0.85, (y.min(), y.max())


def test_tr_bdf2_friction_holds_below_atan_mu_and_slides_above():
    for theta in (15.0, 40.0):
        check_friction_on_a_tilted_plane(C.TRBDF2(), theta)


def test_bad_inputs():
    s0 = C.State.at_rest(SCENE)
    with pytest.raises(ValueError, match="previous= is BDF2's"):
        C.step(SCENE, s0, 1 / 30, TR, previous=s0)
    layers = C.grid(2, 0.1, dtype=np.float64, pins=[], self_contact=True)
    with pytest.raises(ValueError, match="self_contact is not supported with TRBDF2"):
        C.rollout(layers, C.State.at_rest(layers), 1 / 30, 2, TR)
