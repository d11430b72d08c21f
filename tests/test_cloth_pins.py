"""Moving pins (``rollout(..., pins=)``, ``step(..., pins=)``): pinned particles exactly on
their path, the rest solved with them as boundary conditions, in substeps, BDF2, batches,
resumed rollouts and the implicit derivative."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxsim import cloth as C
from _helpers import host_rollout_bisection

jax.config.update("jax_enable_x64", True)

SCENE = C.grid(4, 0.1, mass=0.01, stiffness=50.0, gravity=9.8, damping=0.01, dtype=np.float64)
IDS = np.flatnonzero(np.asarray(SCENE.pinned))
DT = 1 / 30
T = 6
START = C.State.at_rest(SCENE)


def translation(v, T=T, dt=DT, start=0):
    """``(T, K, 3)`` the pins carried at constant velocity ``v`` from their rest positions."""
    t = (np.arange(1, T + 1) + start) * dt
    return np.asarray(SCENE.rest)[IDS][None] + np.asarray(v, np.float64)[None, None] * t[:, None, None]


PATH = translation([0.6, 0.3, 0.0])


def test_pins_lie_exactly_on_their_path_with_its_velocity_and_drag_the_cloth():
    states, infos = C.rollout(SCENE, START, DT, T, pins=PATH)
    assert bool(jnp.all(infos.converged))
    assert np.abs(np.asarray(states.x)[:, IDS] - PATH).max() <= 1e-12
    np.testing.assert_allclose(np.asarray(states.v)[:, IDS], np.broadcast_to([0.6, 0.3, 0.0], PATH.shape),
                               rtol=0, atol=1e-12)
    still, _ = C.rollout(SCENE, START, DT, T)
    free = ~np.asarray(SCENE.pinned)
    drift = np.asarray(states.x)[-1, free].mean(0) - np.asarray(still.x)[-1, free].mean(0)
    assert drift[0] > 0.05 and drift[1] > 0.02  # the cloth follows its pins


def test_a_path_that_stays_at_the_pins_equals_no_path():
    rest = np.broadcast_to(np.asarray(SCENE.rest)[IDS], (T, len(IDS), 3))
    (a, ia), (b, ib) = C.rollout(SCENE, START, DT, T, pins=rest), C.rollout(SCENE, START, DT, T)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-13)
    assert np.array_equal(ia.newton_iters, ib.newton_iters)


def test_step_with_pins_equals_the_rollouts_first_step():
    states, _ = C.rollout(SCENE, START, DT, T, pins=PATH)
    one, info = C.step(SCENE, START, DT, pins=PATH[0])
    assert bool(info.converged)
    # the rollout starts Newton from its extrapolation, the step from x^n: the two
    # converge to the same solution within the solve's tolerance
    np.testing.assert_allclose(one.x, states.x[0], rtol=0, atol=1e-10)
    assert np.abs(np.asarray(one.x)[IDS] - PATH[0]).max() == 0.0


@pytest.mark.slow
def test_substeps_with_moving_pins_equal_halved_steps():
    """A stiff scene whose fast pins need substeps: the compiled bisection moves the pins on
    straight lines, as the host recursion of plain steps does."""
    stiff = C.grid(5, 0.2, mass=1 / 36, stiffness=1e4, gravity=9.8, damping=0.0, dtype=np.float64)
    ids = np.flatnonzero(np.asarray(stiff.pinned))
    sub = C.ImplicitEuler(newton_iters=4, extrapolate=0, max_substep_depth=3)
    plain = dataclasses.replace(sub, max_substep_depth=0)
    p0 = np.asarray(stiff.rest)[ids]
    path = p0[None] + np.array([0.0, 0.0, 1.5])[None, None] * (np.arange(1, 4) * DT)[:, None, None]
    states, infos = C.rollout(stiff, C.State.at_rest(stiff), DT, 3, sub, pins=path)
    host = host_rollout_bisection(stiff, C.State.at_rest(stiff), DT, 3, sub.max_substep_depth, plain, pins=(p0, path))
    counts = []
    for t, (s, n, iters, conv, level) in enumerate(host):  # the rollout's substep memory too
        counts.append(n)
        np.testing.assert_allclose(states.x[t], s.x, rtol=0, atol=1e-11)
        assert int(infos.newton_iters[t]) == iters and int(infos.memory.level[t]) == level
    assert np.asarray(infos.substeps).tolist() == counts and max(counts) > 1
    assert np.abs(np.asarray(states.x)[:, ids] - path).max() <= 1e-12


def test_bdf2_and_a_whole_step_keep_the_pins_on_their_path():
    for integ in (C.BDF2(), C.ImplicitEuler(max_substep_depth=0)):
        states, infos = C.rollout(SCENE, START, DT, T, integ, pins=PATH)
        assert bool(jnp.all(infos.converged)), integ
        assert np.abs(np.asarray(states.x)[:, IDS] - PATH).max() <= 1e-12


def test_chunks_resumed_equal_one_rollout():
    whole, _ = C.rollout(SCENE, START, DT, T, pins=PATH)
    first = C.rollout(SCENE, START, DT, 3, pins=PATH[:3])
    s = C.State(first[0].x[-1], first[0].v[-1])
    second, _ = C.rollout(SCENE, s, DT, 3, pins=PATH[3:], resume=first)
    np.testing.assert_allclose(second.x, whole.x[3:], rtol=0, atol=1e-12)


@pytest.mark.slow
def test_batch_rollout_with_per_scene_and_shared_paths_equals_single_rollouts():
    other = C.replace(SCENE, stiffness=80.0)
    paths = np.stack([PATH, translation([-0.3, 0.0, 0.4])])
    states, infos = C.batch_rollout([SCENE, other], START, DT, T, pins=paths)
    shared, _ = C.batch_rollout([SCENE, other], START, DT, T, pins=PATH)
    for b, scene in enumerate((SCENE, other)):
        ref, _ = C.rollout(scene, START, DT, T, pins=paths[b])
        np.testing.assert_allclose(states.x[b], ref.x, rtol=0, atol=1e-12)
    ref, _ = C.rollout(other, START, DT, T, pins=PATH)
    np.testing.assert_allclose(shared.x[1], ref.x, rtol=0, atol=1e-12)


@pytest.mark.slow
def test_gradients_flow_to_the_pin_path():
    def loss(path):
        states, _ = C.rollout(SCENE, START, DT, 3, pins=path)
        return jnp.sum(states.x[-1, :, 0] ** 2) + jnp.sum(states.v[-1, :, 2])

    check_grads(loss, (jnp.asarray(PATH[:3]),), order=1, modes=("rev",), eps=1e-6)
    g = jax.grad(loss)(jnp.asarray(PATH[:3]))
    assert bool(jnp.all(jnp.isfinite(g))) and float(jnp.abs(g).max()) > 0


@pytest.mark.parametrize("pins, match", [
    (np.zeros((T, 3, 3)), r"pins must have shape \(6, 2, 3\)"),
    (np.zeros((T + 1, 2, 3)), r"pins must have shape \(6, 2, 3\)"),
    (np.full((T, 2, 3), np.nan), "pins must be finite"),
    (np.full((T, 2, 3), "a"), "real numbers"),
])
def test_bad_pins_are_rejected(pins, match):
    with pytest.raises(ValueError, match=match):
        C.rollout(SCENE, START, DT, T, pins=pins)


def test_pins_need_an_implicit_integrator_and_pinned_particles():
    with pytest.raises(ValueError, match="ImplicitEuler, BDF2 or TRBDF2"):
        C.rollout(SCENE, START, DT, T, C.ExplicitEuler(), pins=PATH)
    bare = C.grid(4, 0.1, pins=[], dtype=np.float64)
    with pytest.raises(ValueError, match="has none"):
        C.step(bare, C.State.at_rest(bare), DT, pins=np.zeros((0, 3)))
    three = C.grid(4, 0.1, pins=[0, 1, 2], dtype=np.float64)
    with pytest.raises(ValueError, match="same number of pinned particles"):
        C.batch_rollout([SCENE, three], START, DT, T, pins=PATH)


def test_pins_driven_inside_a_collider_are_refused():
    """A pin path that enters a body capsule would leave every step converged and stable
    around a cloth that passes through the body (a pin is driven, not pushed back): the
    rollout refuses it, naming the pin, the collider and the step, for a still collider and
    a collider path."""
    rest = np.asarray(SCENE.rest)
    body = C.Capsule(rest[IDS[0]] + [-0.25, 0.0, -0.1], rest[IDS[0]] + [-0.25, 0.0, 0.5], 0.06)  # beside the x=0 edge
    scene = C.replace(SCENE, colliders=(body,))
    into = translation([-2.0, 0.0, 0.0])  # the pins move 0.067 m a step toward it: inside from step 2 (0.2 m)
    with pytest.raises(ValueError, match=rf"pinned particle {IDS[0]} is driven inside colliders\[0\] \(Capsule\) "
                                         r"at step 2"):
        C.rollout(scene, START, DT, T, pins=into)
    path = jax.tree_util.tree_map(lambda a: np.broadcast_to(np.asarray(a), (T,) + np.shape(a)), (body,))
    with pytest.raises(ValueError, match="driven inside colliders"):
        C.rollout(scene, START, DT, T, pins=into, colliders=path)
    C.rollout(scene, START, DT, 2, pins=into[:2])  # outside for the first steps: taken
