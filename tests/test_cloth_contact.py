"""Colliders, IPC barrier contact and lagged friction (jaxsim.cloth._model.colliders, _contact)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads

from jaxsim import cloth as C
from jaxsim.cloth._implicit import contact as _contact
from _helpers import all_eqns, check_friction_on_a_tilted_plane, step_jaxpr

SPHERE_C = np.array([0.0, 0.5, 0.0])


def random_colliders(rng):
    n = rng.normal(size=3)
    return [C.Plane(n, 0.3), C.Sphere(rng.normal(size=3), 0.7),
            C.Capsule(rng.normal(size=3), rng.normal(size=3), 0.4), C.Capsule(np.ones(3), np.ones(3), 0.5)]


def ref_distance(c, x):
    if isinstance(c, C.Plane):
        return x @ np.asarray(c.normal) - float(c.offset)
    if isinstance(c, C.Sphere):
        return np.linalg.norm(x - np.asarray(c.center), axis=-1) - float(c.radius)
    a, b = np.asarray(c.a), np.asarray(c.b)
    ab = b - a
    t = np.clip(((x - a) @ ab) / max(ab @ ab, 1e-300), 0, 1)
    return np.linalg.norm(x - (a + t[:, None] * ab), axis=-1) - float(c.radius)


def test_collider_geometry_against_numpy():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(400, 3)) * 2
    u = rng.normal(size=(400, 3)) * 1e-3
    for c in random_colliders(rng):
        d = ref_distance(c, x)
        np.testing.assert_allclose(jax.jit(c.distance)(x), d, atol=1e-12)
        np.testing.assert_allclose(jax.jit(c.distance_from)(x, u), ref_distance(c, x + u), atol=1e-12)
        g = jax.jit(jax.vmap(jax.grad(c.distance)))(x)
        np.testing.assert_allclose(jax.jit(c.normal_at)(x), g, atol=1e-9)
        out = np.asarray(jax.jit(c.push_out)(x, 0.01))
        inside = d < 0.01
        np.testing.assert_allclose(ref_distance(c, out[inside]), 0.01, atol=1e-9)
        np.testing.assert_array_equal(out[~inside], x[~inside])


def test_time_of_impact_is_the_first_touch():
    rng = np.random.default_rng(1)
    ts = np.linspace(0.0, 1.0, 4001)
    for c in random_colliders(rng):
        x = rng.normal(size=(300, 3)) * 2
        x = x[ref_distance(c, x) > 1e-3]
        dx = rng.normal(size=x.shape) * 2
        toi = np.asarray(jax.jit(c.time_of_impact)(x, dx))
        path = ref_distance(c, (x[:, None] + ts[None, :, None] * dx[:, None]).reshape(-1, 3)).reshape(len(x), -1)
        hit = (path <= 0).any(axis=1)
        first = np.where(hit, ts[np.argmax(path <= 0, axis=1)], np.inf)
        np.testing.assert_allclose(toi[hit], first[hit], atol=ts[1] + 1e-9)
        assert np.all(ref_distance(c, x + 0.999 * np.minimum(toi, 1.0)[:, None] * dx) > -1e-12)
        assert np.all(~np.isfinite(toi[~hit]) | (toi[~hit] > 1.0 - ts[1]))


def test_barrier_values_slope_and_nan_free_gradient():
    dhat = 0.01
    d = jnp.linspace(-0.01, 0.02, 301)
    b = jax.jit(_contact.barrier)(d, dhat)
    ref = np.where(d > 0, np.where(d < dhat, -(d - dhat) ** 2 * np.log(np.maximum(d, 1e-300) / dhat), 0.0), np.inf)
    np.testing.assert_allclose(b, ref, rtol=1e-12)
    g = jax.jit(jax.vmap(jax.grad(_contact.barrier), in_axes=(0, None)))(d, dhat)
    assert bool(jnp.all(jnp.isfinite(g)))
    np.testing.assert_allclose(_contact.barrier_slope(d, dhat), jnp.where(d > 0, g, 0.0), rtol=1e-10, atol=1e-14)
    h = jax.jit(jax.vmap(jax.grad(jax.grad(_contact.barrier)), in_axes=(0, None)))(d, dhat)
    assert bool(jnp.all(jnp.isfinite(h))) and bool(jnp.all(h >= 0))
    y2 = jnp.linspace(0.0, 4e-6, 101)
    assert bool(jnp.all(jnp.isfinite(jax.jit(jax.vmap(jax.grad(jax.grad(_contact.f0)), in_axes=(0, None)))(y2, 1e-3))))


@pytest.mark.slow
def test_contact_blocks_are_the_projected_autodiff_hessian():
    from jaxsim.cloth._implicit import problem as _problem

    rng = np.random.default_rng(3)
    for col in (C.Plane(np.array([0.0, 1.0, 0.0]), 0.499, friction=0.3), C.Sphere(np.zeros(3), 0.4995, friction=0.4),
                C.Capsule(np.array([-1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), 0.4995, friction=0.2)):
        c = C.grid(3, 0.1, origin=(-0.15, 0.5, -0.15), gravity=9.8, pins=[], dtype=np.float64, colliders=(col,))
        c = C.replace(c, contact_gap=jnp.asarray(0.01))
        x0 = jnp.asarray(c.rest)
        p = _problem.StepProblem.build(c, x0, jnp.asarray(rng.normal(size=x0.shape) * 0.01), jnp.asarray(1 / 60))
        assert float(jnp.max(p.contact.lam)) > 0  # some particles are in contact
        hess = jax.jit(jax.hessian(lambda v, p: _contact.potential(v, x0, c, p.contact, p.free)))
        blocks = jax.jit(lambda v, p: _contact.blocks(v, x0, c, p.contact, p.free))
        for scale in (0.0, 1e-6, 1e-3):
            u = jnp.asarray(rng.normal(size=x0.shape) * scale) * jnp.array([1.0, 0.0, 1.0]) + jnp.array([0, 1e-4, 0])
            H = hess(u, p)
            exact = jnp.stack([H[i, :, i, :] for i in range(c.num_particles)])
            B = blocks(u, p)
            big = float(jnp.max(jnp.abs(exact)))
            assert float(jnp.min(jnp.linalg.eigvalsh(B))) >= -1e-12 * big
            if isinstance(col, C.Plane):  # no curvature: nothing is projected away
                np.testing.assert_allclose(B, exact, atol=1e-10 * big)
            else:  # only the barrier's negative curvature term is dropped: B - exact is PSD
                assert float(jnp.min(jnp.linalg.eigvalsh(B - exact))) >= -1e-10 * big


# ---- the scene used by the rollouts below (one structure, so one compile per dtype) ----

def scene(dtype, k=1e3, n=3, mu=0.2, sphere=SPHERE_C, origin=(-0.15, 1.0, -0.15), pins=()):
    cols = (C.Plane(np.array([0.0, 1.0, 0.0]), 0.0, friction=mu), C.Sphere(np.asarray(sphere), 0.3, friction=mu),
            C.Capsule(np.array([-1.0, 0.2, 0.6]), np.array([1.0, 0.2, 0.6]), 0.15, friction=mu))
    return C.grid(n, 0.1, origin=origin, mass=0.01, stiffness=k, damping=0.01, gravity=9.8, pins=list(pins), dtype=dtype,
                  colliders=cols)


def min_distance(c, xs):
    xs = np.asarray(xs, np.float64).reshape(-1, 3)
    return min(float(np.min(ref_distance(col, xs))) for col in c.colliders)


def test_a_contact_rollout_lands_on_the_colliders_without_penetrating():
    """The fast tier's contact rollout: a 3x3-cell cloth dropped onto the sphere, the floor
    and the capsule (float64, defaults) for 1 s; every step converges and no particle of
    any frame is inside a collider (numpy distances), and it comes to rest on them."""
    c = scene(np.float64)
    states, infos = C.rollout(c, C.State.at_rest(c), 1 / 30, 30)
    assert bool(jnp.all(infos.converged)) and bool(jnp.all(infos.stable))
    assert min_distance(c, states.x) >= 0.0
    assert float(np.max(np.abs(np.asarray(states.v[-1])))) < 0.05  # at rest
    assert float(np.min(np.asarray(states.x[-1])[:, 1])) > 0.0


@pytest.mark.slow
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_no_penetration_over_stiffness_and_time_step(dtype):
    for k in (1e2, 1e5):
        for dt in (1 / 240, 1 / 30):
            c = scene(dtype, k)
            states, infos = C.rollout(c, C.State.at_rest(c), dt, 500)
            assert bool(jnp.all(infos.stable)), (k, dt)
            assert min_distance(c, states.x) >= 0.0, (k, dt)
            assert float(jnp.mean(infos.converged)) >= 0.9, (k, dt, float(jnp.mean(infos.converged)))
            if dt == 1 / 30:  # it came to rest on the colliders, not below them
                top = np.asarray(states.x[-1])[:, 1]
                assert top.min() > 0.0 and top.max() < 1.0


@pytest.mark.slow
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_no_penetration_with_a_sphere_moving_at_5_m_per_s(dtype):
    dt, T = 1 / 120, 500
    c = scene(dtype, 1e3, sphere=(-2.5, 0.2, 0.0), origin=(-0.15, 0.55, -0.15), pins=(0, 3))  # hangs from 2 corners
    t = np.arange(1, T + 1) * dt
    sx = np.minimum(-2.5 + 5.0 * t, 3.0)  # 5 m/s along x, through the hanging cloth
    path = tuple(jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (T,) + a.shape), col) for col in c.colliders)
    path = (path[0], C.Sphere(np.stack([sx, np.full(T, 0.2), np.zeros(T)], -1), path[1].radius, path[1].friction),
            path[2])
    states, infos = C.rollout(c, C.State.at_rest(c), dt, T, colliders=path)
    assert bool(jnp.all(infos.stable))
    xs = np.asarray(states.x, np.float64)
    for step in range(T):
        cols = (c.colliders[0], C.Sphere(np.array([sx[step], 0.2, 0.0]), 0.3), c.colliders[2])
        assert min(float(np.min(ref_distance(col, xs[step]))) for col in cols) >= 0.0, step
    assert float(np.max(xs[:, :, 1])) > 0.6  # the sphere swept the hanging cloth up and over it
    assert float(jnp.mean(infos.converged)) >= 0.9


@settings(max_examples=4, deadline=None)
@given(st.floats(0.15, 0.45), st.floats(-0.3, 0.3), st.sampled_from([1 / 240, 1 / 60, 1 / 30]),
       st.sampled_from([1e2, 1e4]))
@pytest.mark.slow
def test_property_no_penetration(radius_y, sphere_x, dt, k):
    c = scene(np.float64, k, sphere=(sphere_x, radius_y + 0.05, 0.0))
    states, infos = C.rollout(c, C.State.at_rest(c), dt, 60)
    assert bool(jnp.all(infos.stable))
    assert min_distance(c, states.x) >= 0.0


# ---- friction on a tilted plane ----

@pytest.mark.parametrize("theta", [15.0, 40.0])
@pytest.mark.slow
def test_friction_holds_below_atan_mu_and_slides_above(theta):
    check_friction_on_a_tilted_plane(C.ImplicitEuler(), theta)


def test_friction_smoothing_length_per_dtype():
    """A step smooths friction over its dtype's ``FRICTION_EPS_V`` times ``h``: float32's ramp
    is ten times float64's (docs/performance.md, "Float32 friction")."""
    from jaxsim.cloth._implicit.problem import StepProblem

    assert C.FRICTION_EPS_V[np.dtype(np.float32)] == 10 * C.FRICTION_EPS_V[np.dtype(np.float64)]
    h = 1.0 / 60.0
    for dtype in (np.float32, np.float64):
        c = scene(dtype)
        s = C.State.at_rest(c)
        eps_h = StepProblem.build(c, s.x, s.v, jnp.asarray(h, dtype)).contact.eps_h
        assert eps_h.dtype == dtype
        np.testing.assert_allclose(float(eps_h), C.FRICTION_EPS_V[np.dtype(dtype)] * h, rtol=1e-6)


# ---- what the compiled step holds ----

def primitives(c):
    return {e.primitive.name for e in all_eqns(step_jaxpr(c, C.ImplicitEuler(linear_solver=C.CG())))}


def test_a_scene_without_colliders_compiles_no_contact_terms():
    base = C.grid(4, 0.1, gravity=9.8, dtype=np.float64)
    frictionless = C.replace(base, colliders=(C.Sphere(np.zeros(3), 0.1),))
    frictional = C.replace(base, colliders=(C.Sphere(np.zeros(3), 0.1, friction=0.3),))
    assert "log" not in primitives(base)  # the barrier is the only log in a step
    assert "log" in primitives(frictionless)
    n = [len(list(all_eqns(step_jaxpr(c, C.ImplicitEuler(linear_solver=C.CG()))))) for c in (base, frictionless, frictional)]
    assert n[0] < n[1] < n[2]


# ---- derivatives through contact ----

@pytest.mark.slow
def test_gradients_through_contact_match_finite_differences():
    """The implicit derivative of a step covers the barrier and friction: a cloth resting
    on a sphere, d(final positions)/d(sphere centre) and d/d(stiffness)."""
    c = C.grid(3, 0.1, origin=(-0.15, 0.85, -0.15), mass=0.01, stiffness=1e3, damping=0.01, gravity=9.8, pins=[],
               dtype=np.float64, colliders=(C.Sphere(SPHERE_C, 0.3, friction=0.3),))
    integ = C.ImplicitEuler(linear_solver=C.Cholesky())
    s0 = C.State.at_rest(c)
    for _ in range(20):  # drape (the same compiled step as below)
        s0, _ = C.step(c, s0, 1 / 30, integ)
    assert float(jnp.min(c.colliders[0].distance(s0.x))) < float(c.contact_gap)  # in contact
    weights = jnp.arange(1.0, 1.0 + 3 * c.num_particles).reshape(-1, 3)

    def final_x(center, k):
        sc = C.replace(c, colliders=(C.Sphere(center, 0.3, 0.3),), stiffness=k * jnp.ones(c.num_springs))
        s1, _ = C.step(sc, s0, 1 / 30, integ)
        return jnp.sum(s1.x * weights)

    assert bool(C.step(c, s0, 1 / 30, integ)[1].converged)
    # one function of both (stiffness scaled to order one, so that one eps suits both)
    check_grads(lambda ctr, k: final_x(ctr, 1e3 * k), (jnp.asarray(SPHERE_C), jnp.asarray(1.0)), order=1,
                modes=("rev",), eps=1e-6)  # reverse mode transposes the implicit-function JVP


# ---- boundary checks ----

@pytest.mark.parametrize("make, match", [
    (lambda: C.Sphere(np.zeros(3), -0.1), "radius"),
    (lambda: C.Capsule(np.zeros(3), np.ones(3), 0.0), "radius"),
    (lambda: C.Plane(np.zeros(3), 0.0), "non-zero"),
    (lambda: C.Sphere(np.zeros(3), 0.1, friction=-1.0), "friction"),
    (lambda: C.grid(2, colliders=(C.Sphere(np.array([0.0, 1.5, -1.0]), 0.25),)), "2 free particles"),
    (lambda: C.grid(2, colliders=("floor",)), "Plane, cloth.Sphere or cloth.Capsule"),
])
def test_bad_colliders_raise(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_state_inside_a_collider_and_explicit_euler_raise():
    c = scene(np.float64)
    x = np.asarray(c.rest).copy()
    x[:3, 1] = -0.5
    with pytest.raises(ValueError, match="3 free particles of the state"):
        C.step(c, C.State(x, np.zeros_like(x)), 1 / 60)
    with pytest.raises(ValueError, match="ImplicitEuler"):
        C.step(c, C.State.at_rest(c), 1 / 60, C.ExplicitEuler())
    with pytest.raises(ValueError, match="n_steps first"):
        C.rollout(c, C.State.at_rest(c), 1 / 60, 3, colliders=c.colliders)
