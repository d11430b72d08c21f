"""Adaptive substeps (``ImplicitEuler(max_substep_depth=...)``): the compiled bisection
against a host recursion of plain steps, honest counts, colliders, vmap and gradients."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxsim import cloth as C
from _helpers import host_bisection, host_rollout_bisection

jax.config.update("jax_enable_x64", True)

#: A stiff 6x6 grid on which four Newton iterations do not converge a 1/30 s step, but
#: its halves or quarters do (2 to 4 substeps over the first six steps).
SCENE = C.grid(5, 0.2, mass=1 / 36, stiffness=1e4, gravity=9.8, damping=0.0, dtype=np.float64)
DT = 1 / 30
#: The lab's start on every attempt, so that the host recursion below takes the same
#: Newton iterations as the compiled one.
SUB = C.ImplicitEuler(newton_iters=4, extrapolate=0, max_substep_depth=3)
PLAIN = dataclasses.replace(SUB, max_substep_depth=0)


def test_substeps_equal_the_host_recursion_of_halved_steps():
    """Each step after the first starts at the level the step before left
    (``StepInfo.memory``), as the host's rollout of bisections does."""
    states, infos = C.rollout(SCENE, C.State.at_rest(SCENE), DT, 6, SUB)
    host = host_rollout_bisection(SCENE, C.State.at_rest(SCENE), DT, 6, SUB.max_substep_depth, PLAIN)
    for t, (s, n, iters, conv, level) in enumerate(host):
        np.testing.assert_allclose(states.x[t], s.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(states.v[t], s.v, rtol=0, atol=1e-10)
        assert int(infos.newton_iters[t]) == iters
        assert bool(infos.converged[t]) == conv
        assert int(infos.substeps[t]) == n and int(infos.memory.level[t]) == level
    counts = np.asarray(infos.substeps).tolist()
    assert max(counts) > 2 and min(counts) >= 2  # the scene exercises two levels of halving
    assert int(infos.memory.level[0]) > 0  # and the memory: later steps skip the whole attempt
    assert bool(jnp.all(infos.converged))


def test_a_step_alone_attempts_the_whole_step_first():
    """``step`` has no memory: from the state a rollout reached it bisects from level 0, as
    the host recursion does."""
    states, _ = C.rollout(SCENE, C.State.at_rest(SCENE), DT, 2, SUB)
    s = C.State(states.x[0], states.v[0])
    new, info = C.step(SCENE, s, DT, SUB)
    ref, n, iters, _ = host_bisection(SCENE, s, DT, 0, SUB.max_substep_depth, PLAIN)
    np.testing.assert_allclose(new.x, ref.x, rtol=0, atol=1e-12)
    assert int(info.substeps) == n and int(info.newton_iters) == iters


def test_resumed_chunks_take_the_substeps_of_one_rollout():
    """``rollout(resume=)`` carries ``StepInfo.memory``: 3 + 3 steps take the substeps,
    Newton iterations and states of one 6-step rollout; a chunk started without it
    attempts the whole step first, which costs more."""
    s0 = C.State.at_rest(SCENE)
    whole, iw = C.rollout(SCENE, s0, DT, 6, SUB)
    a, ia = C.rollout(SCENE, s0, DT, 3, SUB)
    nxt = C.State(a.x[-1], a.v[-1])
    b, ib = C.rollout(SCENE, nxt, DT, 3, SUB, resume=(a, ia))
    for got, want in ((ia, slice(0, 3)), (ib, slice(3, 6))):
        assert np.array_equal(got.substeps, iw.substeps[want])
        assert np.array_equal(got.newton_iters, iw.newton_iters[want])
        assert np.array_equal(got.memory.level, iw.memory.level[want])
    np.testing.assert_allclose(b.x, whole.x[3:], rtol=0, atol=1e-12)
    _, bare = C.rollout(SCENE, nxt, DT, 3, SUB)
    assert int(bare.newton_iters[0]) > int(ib.newton_iters[0])


def test_without_substeps_the_same_scene_does_not_converge():
    _, infos = C.rollout(SCENE, C.State.at_rest(SCENE), DT, 6, PLAIN)
    assert not bool(jnp.any(infos.converged)) and bool(jnp.all(infos.stable))
    assert np.asarray(infos.substeps).tolist() == [1] * 6


@pytest.mark.parametrize("extrapolate, atol", [(0, 1e-14), ("auto", 1e-11)])
def test_a_step_that_converges_takes_one_substep_and_equals_the_plain_step(extrapolate, atol):
    """The same Newton iterations as without substeps.  The two programs round apart by
    an ulp; from the lab's start that stays at rounding level, while the extrapolated
    start feeds it through four steps of stiff springs (k h^2 / m = 1e3) to 5e-13 m in
    the suite's -O0 build, far inside the 1e-9 relative gradient the steps converge to."""
    integ = C.ImplicitEuler(max_substep_depth=4, extrapolate=extrapolate)
    (x4, info4), (x0, info0) = (C.rollout(SCENE, C.State.at_rest(SCENE), DT, 4, i)
                                for i in (integ, dataclasses.replace(integ, max_substep_depth=0)))
    assert np.asarray(info4.substeps).tolist() == [1] * 4 and bool(jnp.all(info0.converged))
    np.testing.assert_allclose(x4.x, x0.x, rtol=0, atol=atol)
    assert np.array_equal(info4.newton_iters, info0.newton_iters)


def test_at_the_depth_cap_an_unconverged_substep_is_kept_and_reported():
    """(The deepest level runs ``LAST_NEWTON * newton_iters`` iterations, here 2; Cholesky,
    since PCG's forcing term depends on ``newton_iters``.)"""
    integ = dataclasses.replace(SUB, newton_iters=1, max_substep_depth=2, linear_solver=C.Cholesky())
    s, info = C.step(SCENE, C.State.at_rest(SCENE), DT, integ)
    ref, n, iters, conv = host_bisection(SCENE, C.State.at_rest(SCENE), DT, 0, 2,
                                         dataclasses.replace(integ, max_substep_depth=0))
    assert int(info.substeps) == n == 4 and not conv
    assert not bool(info.converged) and bool(info.stable) and int(info.newton_iters) == iters
    np.testing.assert_allclose(s.x, ref.x, rtol=0, atol=1e-12)


def test_substeps_with_a_moving_collider_and_friction_equal_halved_steps():
    sphere0 = C.Sphere(jnp.array([0.0, 0.60, 0.0]), 0.3, friction=0.4)
    sphere1 = C.Sphere(jnp.array([0.0, 0.64, 0.02]), 0.3, friction=0.4)
    c = C.grid(4, 0.1, origin=(-0.2, 0.95, -0.2), mass=0.02, stiffness=3e3, damping=0.0, gravity=9.8, pins=[],
               colliders=(sphere0,), dtype=np.float64)
    integ = C.ImplicitEuler(newton_iters=3, max_substep_depth=2)
    s = C.State(jnp.asarray(c.rest), jnp.broadcast_to(jnp.array([0.0, -1.5, 0.0]), c.rest.shape))
    path = (jax.tree_util.tree_map(lambda a: a[None], sphere1),)
    states, infos = C.rollout(c, s, DT, 1, integ, colliders=path)
    ref, n, iters, conv = host_bisection(c, s, DT, 0, 2, dataclasses.replace(integ, max_substep_depth=0),
                                         colliders=((sphere0,), (sphere1,)))
    assert int(infos.substeps[0]) == n > 1
    assert int(infos.newton_iters[0]) == iters and bool(infos.converged[0]) == conv
    np.testing.assert_allclose(states.x[0], ref.x, rtol=0, atol=1e-12)


def test_batch_rollout_counts_substeps_per_scene():
    soft = C.replace(SCENE, stiffness=SCENE.stiffness / 100)
    batch = C.stack_scenes([SCENE, soft])
    states, infos = C.batch_rollout(batch, C.State.at_rest(SCENE), DT, 3, SUB)
    for b, scene in enumerate((SCENE, soft)):
        ref, rinfo = C.rollout(scene, C.State.at_rest(scene), DT, 3, SUB)
        assert np.array_equal(infos.substeps[b], rinfo.substeps)
        np.testing.assert_allclose(states.x[b], ref.x, rtol=0, atol=1e-12)
    assert int(jnp.max(infos.substeps[0])) > 1 and int(jnp.max(infos.substeps[1])) == 1


def test_check_grads_through_a_substepped_step():
    c = C.grid(2, 0.2, mass=1 / 9, stiffness=1e4, gravity=9.8, damping=0.1, dtype=np.float64)
    integ = C.ImplicitEuler(newton_iters=3, linear_solver=C.Cholesky(), max_substep_depth=2)
    s0 = C.State.at_rest(c)
    s0, _ = C.step(c, s0, DT, integ)  # moving
    _, info = C.step(c, s0, DT, integ)
    assert int(info.substeps) > 1 and bool(info.converged)
    w = jnp.arange(1.0, 1.0 + 3 * c.num_particles).reshape(-1, 3)

    def f(x, k):
        s1, _ = C.step(C.replace(c, stiffness=1e4 * k * jnp.ones(c.num_springs)), C.State(x, s0.v), DT, integ)
        return jnp.sum(s1.x * w) + jnp.sum(s1.v * w)

    check_grads(f, (s0.x, jnp.asarray(1.0)), order=1, modes=("fwd", "rev"), eps=1e-6)


@pytest.mark.parametrize("depth", [-1, 11, True, 2.0])
def test_bad_max_substep_depth_raises(depth):
    with pytest.raises(ValueError, match="max_substep_depth"):
        C.ImplicitEuler(max_substep_depth=depth)
