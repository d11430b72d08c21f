"""Wind, drag and lift (``Cloth(wind=, drag=, lift=)``, ``rollout(wind=)``): forces against a
NumPy flat-plate reference, the Hessian against ``jax.hessian``, a cloth blown downwind,
nothing compiled without them, and bad input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxsim import cloth as C
from jaxsim.cloth._implicit import direction as dr
from jaxsim.cloth._implicit import parts
from jaxsim.cloth._implicit import problem as pr
from jaxsim.cloth._implicit.setup import NewtonSetup
from _helpers import all_eqns, step_jaxpr

jax.config.update("jax_enable_x64", True)

#: A 7x7 cloth standing in the x-y plane, facing a wind along +z (no gravity, no pins).
_FLAT = C.grid(6, 0.1, origin=(0.0, 1.0, 0.0), mass=0.01, stiffness=50.0, gravity=0.0, pins=[], dtype=np.float64)
REST = (np.asarray(_FLAT.rest) - [0, 1, 0]) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0.0]]).T + [0, 1, 0]
FACING = C.grid(6, 0.1, mass=0.01, stiffness=50.0, gravity=0.0, pins=[], dtype=np.float64, wind=(0.0, 0.0, 3.0),
                drag=0.6, lift=0.3)
FACING = C.replace(FACING, rest=jnp.asarray(REST))
AT_REST = C.State(jnp.asarray(REST), jnp.zeros_like(jnp.asarray(REST)))
DT = 1 / 30


def reference_forces(faces, x, v, wind, drag, lift):
    """``(N, 3)`` the flat-plate drag ``-drag A |r| r n`` and lift
    ``-lift A r (|q|^2 n - r q) / |q|`` of every triangle, a third on each corner (NumPy)."""
    F = np.zeros_like(x)
    for f in faces:
        a, b, c = x[f]
        cr = np.cross(b - a, c - a)
        n, A = cr / np.linalg.norm(cr), np.linalg.norm(cr) / 2
        q = v[f].mean(0) - wind
        r = n @ q
        force = -drag * A * abs(r) * r * n - lift * A * r * (q @ q * n - r * q) / np.linalg.norm(q)
        F[f] += force / 3
    return F


def test_the_forces_are_the_flat_plate_model():
    """At the displacement ``u = h v`` the step's wind potential pushes with the forces at ``v``
    (lift lagged at the start's ``v``, drag implicit at ``v`` itself)."""
    rng = np.random.default_rng(0)
    x = REST + 0.02 * rng.normal(size=REST.shape)
    v = rng.normal(size=REST.shape)
    p = pr.StepProblem.build(FACING, jnp.asarray(x), jnp.asarray(v), jnp.asarray(DT))
    w = jnp.asarray(DT * v) - p.prediction  # so u = h v
    got = -jax.jit(jax.grad(parts._aero_potential))(w, p)
    want = reference_forces(np.asarray(FACING.contact_faces), x, v, np.array([0, 0, 3.0]), 0.6, 0.3)
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)


def test_newtons_gradient_and_hessian_with_wind_are_the_energys():
    rng = np.random.default_rng(1)
    p = pr.StepProblem.build(FACING, AT_REST.x, jnp.asarray(rng.normal(size=REST.shape)), jnp.asarray(DT))
    w = jnp.asarray(0.01 * rng.normal(size=REST.shape))
    t = pr.spring_terms(w, p)
    np.testing.assert_allclose(jax.jit(pr.gradient)(w, p, t), jax.jit(jax.grad(pr.incremental_potential))(w, p),
                               rtol=0, atol=1e-11)
    sv = NewtonSetup(p, C.ImplicitEuler(linear_solver=C.Cholesky()))
    parts = dr.hessian_parts(sv, w, t)
    H = jax.jit(jax.hessian(lambda a, p: pr.incremental_potential(a.reshape(-1, 3), p)))(w.reshape(-1), p)
    np.testing.assert_allclose(dr.assembled(sv, parts.exact, parts.contact, pairs=parts.pairs), H, rtol=0,
                               atol=1e-10)


def test_a_cloth_in_a_wind_moves_downwind_and_without_drag_not_at_all():
    states, infos = C.rollout(FACING, AT_REST, DT, 8)
    assert bool(jnp.all(infos.converged))
    dz = np.asarray(states.x[:, :, 2] - REST[:, 2]).mean(1)
    assert dz[-1] > 0.05 and np.all(np.diff(dz) > 0)
    back, _ = C.rollout(FACING, AT_REST, DT, 8, wind=np.tile([0.0, 0.0, -3.0], (8, 1)))
    np.testing.assert_allclose(np.asarray(back.x[-1, :, 2]) - REST[:, 2], -(np.asarray(states.x[-1, :, 2]) - REST[:, 2]),
                               atol=1e-10)
    still, _ = C.rollout(C.replace(FACING, drag=0.0, lift=0.0), AT_REST, DT, 8)
    assert float(jnp.abs(still.x - REST).max()) <= 1e-15


def test_a_scene_without_drag_or_lift_compiles_no_wind_code():
    plain = C.grid(3, 0.1, dtype=np.float64)
    calm = C.grid(3, 0.1, dtype=np.float64, wind=(1.0, 0.0, 0.0), drag=0.0)
    windy = C.grid(3, 0.1, dtype=np.float64, wind=(1.0, 0.0, 0.0), drag=0.5)
    assert not calm.aero and windy.aero
    integ = C.ImplicitEuler(linear_solver=C.CG())
    n = [len(list(all_eqns(step_jaxpr(c, integ)))) for c in (plain, calm, windy)]
    assert n[0] == n[1] < n[2]


@pytest.mark.slow
def test_gradients_flow_to_drag_and_wind():
    def final(drag, wind):
        scene = C.replace(FACING, drag=drag, wind=wind)
        states, _ = C.rollout(scene, AT_REST, DT, 3)
        return jnp.sum(states.x[-1, :, 2]) + jnp.sum(states.x[-1, :, 0] ** 2)

    check_grads(final, (jnp.asarray(0.6), jnp.asarray([0.5, 0.0, 3.0])), order=1, modes=("rev",), eps=1e-6)


@pytest.mark.slow
def test_batch_rollout_with_wind_equals_single_rollouts():
    other = C.replace(FACING, drag=0.3, wind=jnp.asarray([0.0, 1.0, 2.0]))
    states, _ = C.batch_rollout([FACING, other], AT_REST, DT, 4)
    for b, scene in enumerate((FACING, other)):
        ref, _ = C.rollout(scene, AT_REST, DT, 4)
        np.testing.assert_allclose(states.x[b], ref.x, rtol=0, atol=1e-12)


@pytest.mark.parametrize("make, match", [
    (lambda: C.replace(C.grid(3, 0.1, dtype=np.float64), drag=1.0), "act on the scene's triangles"),
    (lambda: C.grid(3, 0.1, drag=-1.0), "drag"),
    (lambda: C.grid(3, 0.1, drag=1.0, wind=(0.0, np.nan, 0.0)), "wind must be finite"),
    (lambda: C.grid(3, 0.1, drag=1.0, wind=(0.0, 1.0)), r"wind must have shape \(3\)"),
    (lambda: C.rollout(FACING, AT_REST, DT, 3, wind=np.zeros((2, 3))), r"shape \(3, 3\)"),
    (lambda: C.rollout(C.grid(3, 0.1), C.State.at_rest(C.grid(3, 0.1)), DT, 3, wind=np.zeros((3, 3))),
     "needs a scene with drag or lift"),
    (lambda: C.rollout(FACING, AT_REST, DT, 3, C.ExplicitEuler()), "ImplicitEuler, BDF2 or TRBDF2"),
])
def test_bad_wind_input_is_rejected(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_a_wind_without_drag_or_lift_is_refused_not_ignored():
    """``grid(..., wind=)`` with neither ``drag`` nor ``lift`` would move nothing: it raises,
    naming the wind; ``drag=0.0`` given on purpose keeps the still scene."""
    with pytest.raises(ValueError, match=r"wind=\(5.0, 0.0, 0.0\) moves nothing without drag or lift"):
        C.grid(3, 0.1, wind=(5.0, 0.0, 0.0))
    assert not C.grid(3, 0.1, wind=(5.0, 0.0, 0.0), drag=0.0).aero
    assert not C.grid(3, 0.1, wind=(0.0, 0.0, 0.0)).aero
