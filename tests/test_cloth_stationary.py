"""Newton's stationary-point steps (``_implicit.newton.STATIONARY_REL``) and PCG through negative curvature."""

import dataclasses
import pytest
import os

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import cloth as C
from jaxsim.cloth._implicit.linsolve import pcg

from _helpers import stiff_grid


def _indefinite_system(n=30, seed=0):
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    lam = rng.uniform(1.0, 10.0, n) * np.where(np.arange(n) % 3 == 0, -1.0, 1.0)
    return (Q * lam) @ Q.T, rng.normal(size=n)


def test_pcg_through_negative_curvature_solves_a_symmetric_indefinite_system():
    A, b = _indefinite_system()
    Aj, bj = jnp.asarray(A), jnp.asarray(b)
    Dinv = 1.0 / np.abs(np.diag(A))  # an SPD (diagonal) preconditioner
    for Minv in (lambda r: r, lambda r: jnp.asarray(Dinv) * r):
        x, k, res, broke = pcg(lambda v: Aj @ v, bj, jnp.zeros_like(bj), Minv, tol=1e-12, max_iters=500,
                               indefinite=True)
        assert not bool(broke) and float(res) <= 1e-12 and 0 < int(k) < 500
        np.testing.assert_allclose(np.asarray(x), np.linalg.solve(A, b), rtol=1e-9, atol=1e-11)
        # the minimising PCG stops at the first non-positive curvature instead
        _, k2, res2, broke2 = pcg(lambda v: Aj @ v, bj, jnp.zeros_like(bj), Minv, tol=1e-12, max_iters=500)
        assert bool(broke2) and int(k2) < int(k) and float(res2) > 1e-3


def test_pcg_modes_agree_on_a_positive_definite_system():
    A, b = _indefinite_system()
    A = A @ A + np.eye(len(b))
    Aj, bj = jnp.asarray(A), jnp.asarray(b)
    out = [pcg(lambda v: Aj @ v, bj, jnp.zeros_like(bj), lambda r: r, tol=1e-10, max_iters=500, indefinite=m)
           for m in (False, True)]
    np.testing.assert_array_equal(np.asarray(out[0][0]), np.asarray(out[1][0]))
    assert int(out[0][1]) == int(out[1][1]) and not bool(out[0][3]) and not bool(out[1][3])


def _backward_euler_residual(c, x0, v0, x, h):
    """``max_i |r_i| / max_i scale_i`` of backward Euler's equations at the new positions
    ``x`` (numpy, float64): ``M (x - x0 - h v0) / h^2 = M g + f_springs(x) + f_damping``,
    with the damping direction frozen at ``x0``; pinned particles left out."""
    x0, v0, x = (np.asarray(a, np.float64) for a in (x0, v0, x))
    i, j = np.asarray(c.springs).T
    k, L, m = np.asarray(c.stiffness), np.asarray(c.rest_length), np.asarray(c.mass)
    d = x[j] - x[i]
    l = np.linalg.norm(d, axis=1)
    fs = (k * (l - L) / l)[:, None] * d  # on i, towards j
    e0 = (x0[j] - x0[i]) / np.linalg.norm(x0[j] - x0[i], axis=1)[:, None]
    du = (x - x0)[j] - (x - x0)[i]
    fd = (float(c.damping) / h * np.sum(e0 * du, axis=1))[:, None] * e0
    f = np.zeros_like(x)
    np.add.at(f, i, fs + fd)
    np.add.at(f, j, -(fs + fd))
    mag = np.zeros(len(x))
    np.add.at(mag, i, np.linalg.norm(fs + fd, axis=1))
    np.add.at(mag, j, np.linalg.norm(fs + fd, axis=1))
    g = np.asarray(c.gravity)
    inertia = m[:, None] * (x - x0 - h * v0) / h**2
    r = inertia - m[:, None] * g - f
    free = ~np.asarray(c.pinned)
    scale = np.linalg.norm(inertia, axis=1) + m * np.linalg.norm(g) + mag
    return np.max(np.linalg.norm(r, axis=1)[free]) / np.max(scale[free])


@pytest.mark.slow
def test_buckling_steps_of_scene_c_64_converge_at_a_stationary_point():
    """Scene C 64x64 at k = 1e3, 10 steps from rest, float64, two-level CG.  On its ninth and
    tenth steps the exact Hessian is indefinite near the solution; the shifted Hessian alone
    converged linearly there (0.75 per iteration) and neither step converged within the
    default cap of 20.  Solving the exact Hessian for the stationary point, each of the ten
    converges in at most 11 iterations, and the new positions solve backward Euler's
    equations (checked in numpy, independently of the solver's own gradient)."""
    c = stiff_grid(63)
    h = 1 / 30
    integ = C.ImplicitEuler(linear_solver=C.CG(C.TwoLevel()), trace=True, max_substep_depth=0)  # one Newton solve a step
    states, info = jax.jit(lambda s: C.rollout(c, s, h, 10, integ))(C.State.at_rest(c))
    iters = np.asarray(info.newton_iters)
    assert np.all(np.asarray(info.converged)) and iters.max() <= 12, iters
    used = np.concatenate([np.asarray(info.trace.hessian[s, : iters[s]]) for s in (8, 9)])
    assert np.sum(used == C.HESSIANS.index("stationary")) >= 3
    for s in (8, 9):
        x0, v0 = np.asarray(states.x[s - 1]), np.asarray(states.v[s - 1])
        assert _backward_euler_residual(c, x0, v0, states.x[s], h) < 1e-8


@pytest.mark.slow
def test_a_stationary_phase_converges_where_its_first_step_raises_the_gradient(monkeypatch):
    """Scene C 32x32 k = 1e5, float64: the step 35 steps from rest (state and extrapolated
    start saved from a rollout, ``tests/data``).  Near its solution the exact Hessian has an
    eigenvalue of -0.005 against the inertia's 0.88: the shifted Hessian moves 3% of the way
    per iteration, and the full step to the stationary point first raises the relative
    gradient (6.6e-9 to 2.8e-6) before the next ones converge quadratically.  Single
    stationary-point tries (the first rejected) left the step at the 20-iteration cap;
    the phase converges within it, to positions that solve backward Euler's equations."""
    from jaxsim.cloth._implicit import newton as _newton

    c = stiff_grid(31, k=1e5)
    h = 1 / 30
    data = np.load(os.path.join(os.path.dirname(__file__), "data", "c32_k1e5_hard_step.npz"))
    state = C.State(data["x"], data["v"])
    integ = C.ImplicitEuler(linear_solver=C.CG(C.TwoLevel()), trace=True, max_substep_depth=0)  # one Newton solve a step
    new, info = C.step(c, state, h, integ, guess=data["guess"])
    n = int(info.newton_iters)
    assert bool(info.converged) and n < 20, (n, float(info.rel_grad))
    assert _backward_euler_residual(c, data["x"], data["v"], new.x, h) < 1e-8
    used = np.asarray(info.trace.hessian[:n])
    rel = np.asarray(info.trace.rel[:n])
    phase = np.flatnonzero(used == C.HESSIANS.index("stationary"))
    assert len(phase) >= 3 and rel[phase[0]] > 10 * rel[phase[0] - 1]  # the first step raised it
    # one step per try, as before the phase: the cap
    monkeypatch.setattr(_newton, "STATIONARY_STEPS", 1)
    single = dataclasses.replace(integ, linear_solver=dataclasses.replace(integ.linear_solver,
                                                                 max_iters=integ.linear_solver.max_iters + 1))  # a new trace
    _, info1 = C.step(c, state, h, single, guess=data["guess"])
    assert not bool(info1.converged) and int(info1.newton_iters) == 20
