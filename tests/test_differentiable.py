"""Gradients through IK and cloth (float64), inverse problems, and NaN-free derivatives."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxsim import cloth as C
from jaxsim import ik

from _helpers import SETTINGS

# ---- IK: implicit-function derivatives against the unrolled ones ----


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["ccd", "fabrik"])
def test_ik_implicit_gradient_equals_unrolled_at_converged_solution(solver):
    arm = ik.lab_arm()

    def jacobians(t, off, iters, out, argnums=(0, 1)):
        def f(t, off, implicit):
            r = ik.solve(ik.Chain(off), t, solver=SETTINGS[solver](iters, 0.0, implicit_diff=implicit))
            return r.positions[-1] if out == "end" else r.positions

        unrolled = jax.jacfwd(f, argnums=argnums)(t, off, False)
        implicit = jax.jacrev(f, argnums=argnums)(t, off, True)
        return unrolled, implicit

    t = jnp.array([0.6, 0.3, 0.4])
    assert float(ik.solve(arm, t, solver=solver, max_iters=100, tol=0.0).error[0]) < 1e-12
    unrolled, implicit = jax.jit(jacobians, static_argnums=(2, 3))(t, arm.offsets, 100, "end")
    for u, i in zip(unrolled, implicit):
        np.testing.assert_allclose(i, u, atol=1e-6)
    np.testing.assert_allclose(implicit[0], np.eye(3), atol=1e-9)  # d end / d target = I when reachable

    # unreachable: every joint position is unique (the straight chain), so compare all of them
    # CCD needs 3000 sweeps to converge there: its unrolled Jacobian is taken for the target
    # only (the offsets' implicit derivative at an unreachable target is FABRIK's case)
    far = jnp.array([2.5, 1.0, -2.0])
    iters, argnums = (100, (0, 1)) if solver == "fabrik" else (3000, (0,))
    unrolled, implicit = jax.jit(jacobians, static_argnums=(2, 3, 4))(far, arm.offsets, iters, "all", argnums)
    for u, i in zip(unrolled, implicit):
        np.testing.assert_allclose(i, u, atol=1e-6)
    assert np.abs(np.asarray(implicit[0])).max() > 0.1  # not trivially zero


@pytest.mark.parametrize("solver", ["ccd", "fabrik"])
@pytest.mark.slow
def test_ik_implicit_gradients_finite_at_singular_poses(solver):
    arm = np.asarray(ik.lab_arm().offsets)
    straight = np.asarray(ik.straight_chain([1.0, 1.0, 1.0, 1.0], direction=(0, 0, 1)).offsets)
    cases = [(arm, [0.0, 1.7, 0.0]), (straight, [0.0, 0.0, 1.5]), (straight, [0.0, 0.0, 5.0])]
    offsets = jnp.asarray(np.stack([c[0] for c in cases]))
    targets = jnp.asarray(np.array([c[1] for c in cases]))

    def loss(t, off):
        r = ik.solve(ik.Chain(off), t, solver=SETTINGS[solver](50, implicit_diff=True))
        return jnp.sum(r.positions[-1]) + jnp.sum(r.rotations)

    g = jax.jit(jax.vmap(jax.grad(loss, argnums=(0, 1))))(targets, offsets)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in g)


# Inverse problem 1 (bone lengths from reach data, to 1e-3, by Adam through fk and the solver)
# runs in notebooks/03_differentiable.ipynb, whose cell asserts the target.


# ---- cloth: implicit differentiation of a step, checked against finite differences ----


@pytest.fixture(scope="module")
def small():
    c = C.grid(3, 0.2, damping=0.5, pins=[0, 3])
    x = np.asarray(c.rest) + 0.02 * np.random.default_rng(0).normal(size=c.rest.shape)
    v = 0.1 * np.random.default_rng(1).normal(size=c.rest.shape)
    return c, jnp.asarray(x), jnp.asarray(v)


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["dense", "cg"])
def test_cloth_step_gradients_check_grads(small, solver):
    c, x, v = small
    integ = C.ImplicitEuler(linear_solver=C.Cholesky() if solver == "dense" else C.CG(tol=1e-12), tol=1e-12)

    def out(x0, v0, k, k_spring, mass, rest_length):
        scene = C.replace(c, stiffness=k * k_spring, mass=mass, rest_length=rest_length)
        s, _ = C.step(scene, C.State(x0, v0), 1 / 60, integ)
        return jnp.concatenate([s.x.ravel(), s.v.ravel()])

    args = (x, v, jnp.float64(1.0), c.stiffness, c.mass, c.rest_length)
    check_grads(out, args, order=1, modes=("fwd", "rev"), atol=1e-5, rtol=1e-5, eps=1e-6)
    # the pinned positions carry the pins: d x_pin / d x0_pin = I, exactly
    J = jax.jacrev(lambda x0: out(x0, *args[1:])[: x.size].reshape(x.shape)[0])(x)
    np.testing.assert_array_equal(np.asarray(J[:, 0]), np.eye(3))


@pytest.mark.slow
def test_rollout_gradient_with_and_without_checkpoint(small):
    c, x, v = small
    s0 = C.State(x, v)

    def loss(k, checkpoint):
        states, _ = C.rollout(C.replace(c, stiffness=k), s0, 1 / 60, 30, checkpoint=checkpoint)
        return jnp.sum(states.x[-1] ** 2) + jnp.sum(states.v[10])

    compiled = [jax.jit(jax.grad(loss), static_argnums=1).lower(120.0, ck).compile() for ck in (False, True)]
    g0, g1 = (f(120.0) for f in compiled)
    np.testing.assert_allclose(g1, g0, rtol=1e-10)
    eps = 1e-4
    fd = (loss(120.0 + eps, False) - loss(120.0 - eps, False)) / (2 * eps)
    np.testing.assert_allclose(g0, fd, rtol=1e-6)
    mem = [f.memory_analysis().temp_size_in_bytes for f in compiled]
    assert mem[1] < mem[0], mem


@pytest.mark.slow
def test_cloth_gradients_finite_at_zero_length_spring_and_fully_pinned():
    # a spring of rest length 0.2 whose two particles start at the same point
    scene = C.Cloth(rest=np.array([[0.0, 0, 0], [0.0, 0, 0], [0.2, 0, 0]]), springs=np.array([[0, 1], [1, 2]]),
                    rest_length=np.array([0.2, 0.2]), stiffness=np.array([100.0, 100.0]), mass=np.ones(3),
                    pinned=np.array([True, False, False]), gravity=np.array([0.0, -9.8, 0.0]), damping=np.asarray(0.3))
    s0 = C.State.at_rest(scene)
    for integ in (C.ImplicitEuler(linear_solver=C.CG()), C.ExplicitEuler(substeps=4)):
        def loss(x0, k):
            s, info = C.step(C.replace(scene, stiffness=k), C.State(x0, s0.v), 1 / 60, integ)
            return jnp.sum(s.x ** 2) + jnp.sum(s.v), info

        (val, info), g = jax.value_and_grad(loss, argnums=(0, 1), has_aux=True)(s0.x, scene.stiffness)
        assert np.isfinite(float(val)) and bool(info.stable)
        assert all(np.all(np.isfinite(np.asarray(a))) for a in g), integ

    pinned = C.grid(2, 0.2, pins=list(range(9)))
    s0 = C.State.at_rest(pinned)
    for integ in (C.ImplicitEuler(linear_solver=C.Cholesky()),):
        J = jax.jacrev(lambda x0: C.step(pinned, C.State(x0, s0.v), 1 / 60, integ)[0].x)(s0.x)
        np.testing.assert_array_equal(np.asarray(J).reshape(27, 27), np.eye(27))


# Inverse problems 2 (stiffness and damping from motion, within 1%) and 3 (control of the
# free corner, to 1e-7 m) run at full size in notebooks/03_differentiable.ipynb, whose cells
# assert those targets; tests/test_notebooks.py executes it.


def test_the_default_early_loop_differentiates_as_the_scan():
    """``early_exit=None`` (the default): undifferentiated, the sweeps run in a while loop; under
    ``jax.grad`` (also through a ``jit``, which hides the grad from the boundary) and ``jax.jvp``
    the value and derivative are the fixed-length scan's."""
    arm = ik.lab_arm()
    t = jnp.asarray(np.asarray(arm.root) + np.array([[0.6, 0.3, 0.4], [0.5, -0.2, 0.9]]))

    def end(settings):
        return lambda tt: jnp.sum(ik.solve(arm, tt, solver=settings).positions[:, -1] ** 2)

    default, scan = end(ik.FABRIK(40, 1e-9)), end(ik.FABRIK(40, 1e-9, early_exit=False))
    prims = {e.primitive.name for e in jax.make_jaxpr(default)(t).jaxpr.eqns}
    assert "custom_jvp_call" in prims
    np.testing.assert_allclose(jax.jit(default)(t), scan(t), rtol=1e-12)
    np.testing.assert_allclose(jax.grad(jax.jit(default))(t), jax.grad(scan)(t), rtol=1e-10, atol=1e-12)
    v = jnp.ones_like(t)
    np.testing.assert_allclose(jax.jvp(default, (t,), (v,))[1], jax.jvp(scan, (t,), (v,))[1], rtol=1e-10)
