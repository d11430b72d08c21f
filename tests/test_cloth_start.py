"""Newton's start: the constant-acceleration extrapolation that ``rollout`` uses, the
``guess`` of ``step``, and the guard that keeps the lab's start wherever it is lower."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import cloth as C
from jaxsim.cloth._implicit import problem as pr
from jaxsim.cloth._model.energy import forces
from jaxsim.cloth._explicit import damping_forces
from jaxsim.cloth._implicit.extrapolate import SMOOTH_NEWTON, History, acceleration
from jaxsim.cloth._implicit.resume import Resume
from jaxsim.cloth._implicit.step import implicit

DT = 1 / 60
INTEG = C.ImplicitEuler(linear_solver=C.CG(), tol=1e-6, extrapolate=1)
LAB = dataclasses.replace(INTEG, extrapolate=False)
STEPS = 6


@pytest.fixture(scope="module")
def moving():
    """A soft 10x10 grid (scene B's constants) 20 steps into its swing, and the state before."""
    c = C.grid(9, 0.2)
    s = C.State.at_rest(c)
    for _ in range(3):  # the compiled rollout of the tests below
        states, _ = C.rollout(c, s, DT, STEPS, LAB)
        s = C.State(states.x[-1], states.v[-1])
    return c, C.State(states.x[-2], states.v[-2]), s


@pytest.mark.parametrize("damping", [0.0, 0.3])
@pytest.mark.slow
def test_start_objective_is_the_incremental_potential_at_the_labs_start(moving, damping):
    c, _, s = moving
    c = C.replace(c, damping=damping)
    p = pr.StepProblem.build(c, s.x, s.v, jnp.asarray(DT))
    want = pr.incremental_potential(p.start, p)
    np.testing.assert_allclose(float(pr.start_objective(p)), float(want), rtol=1e-12)


def before(c, s):
    """``v^{n-1}, v^{n-2}`` of the backward-Euler motion that ends at ``s``, from the
    forces by ``jax.grad`` of the energy (``History.before`` sums them in the radial form)."""
    a = lambda x, v: (forces(c, x) + damping_forces(c, x, v)) / c.mass[:, None] * (~c.pinned)[:, None]  # noqa: E731
    v1 = s.v - DT * a(s.x, s.v)
    return v1, v1 - DT * a(s.x - DT * s.v, v1)


def test_acceleration_is_the_forces_over_the_masses(moving):
    c, _, s = moving
    for damping in (0.0, 0.3):
        cd = C.replace(c, damping=damping)
        want = (forces(cd, s.x) + damping_forces(cd, s.x, s.v)) / cd.mass[:, None] * (~cd.pinned)[:, None]
        np.testing.assert_allclose(np.asarray(acceleration(cd, s.x, s.v)), np.asarray(want), rtol=0, atol=1e-12)
    assert np.all(np.asarray(acceleration(c, s.x, s.v))[np.asarray(c.pinned)] == 0)


def test_rollout_extrapolates_and_saves_a_newton_iteration(moving):
    """On a smoothly swinging grid every step, the first too (its velocities before come
    from the forces), starts one Newton iteration closer (3 -> 2 at the lab's tolerances),
    and ends at the same converged positions."""
    c, _, s = moving
    ex, i_ex = C.rollout(c, s, DT, STEPS, INTEG)
    lab, i_lab = C.rollout(c, s, DT, STEPS, LAB)
    assert bool(jnp.all(i_ex.converged)) and bool(jnp.all(i_lab.converged))
    n_ex, n_lab = np.asarray(i_ex.newton_iters), np.asarray(i_lab.newton_iters)
    assert np.all(n_ex <= n_lab - 1), (n_ex, n_lab)
    np.testing.assert_allclose(np.asarray(ex.x), np.asarray(lab.x), atol=1e-9)
    np.testing.assert_allclose(np.asarray(ex.v), np.asarray(lab.v), atol=1e-7)


def test_rollout_equals_stepping_by_hand_with_the_extrapolated_guess(moving):
    c, _, s = moving
    states, infos = C.rollout(c, s, DT, STEPS, INTEG)
    (prev_v, _), cur = before(c, s), s
    for t in range(3):
        guess = cur.x + DT * (2 * cur.v - prev_v)
        prev_v = cur.v
        cur, info = C.step(c, cur, DT, INTEG, guess=guess)
        assert int(info.newton_iters) == int(infos.newton_iters[t])
        np.testing.assert_allclose(np.asarray(cur.x), np.asarray(states.x[t]), rtol=0, atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("bad", ["far", "nan"])
def test_a_worse_guess_keeps_the_labs_start(moving, bad):
    """A guess 1 m off (huge spring energy), or a NaN one under jit, is not taken: the
    step is the one without a guess, and nothing is NaN."""
    c, _, s = moving
    guess = s.x + 1.0 if bad == "far" else jnp.full_like(s.x, jnp.nan)
    want, i_want = C.step(c, s, DT, INTEG)
    got, i_got = jax.jit(lambda g: C.step(c, s, DT, INTEG, guess=g))(guess)
    assert int(i_got.newton_iters) == int(i_want.newton_iters) and bool(i_got.converged)
    np.testing.assert_allclose(np.asarray(got.x), np.asarray(want.x), rtol=0, atol=1e-13)
    assert bool(jnp.all(jnp.isfinite(got.x)))


def test_pinned_rows_of_the_guess_are_ignored(moving):
    c, prev, s = moving
    guess = s.x + DT * (2 * s.v - prev.v)
    pinned = np.asarray(c.pinned)
    assert pinned.any()
    moved = guess.at[np.flatnonzero(pinned)].add(0.05)  # would stretch the pinned springs
    a, ia = C.step(c, s, DT, INTEG, guess=guess)
    b, ib = C.step(c, s, DT, INTEG, guess=moved)
    np.testing.assert_array_equal(np.asarray(a.x), np.asarray(b.x))
    np.testing.assert_array_equal(np.asarray(b.x)[pinned], np.asarray(s.x)[pinned])


def test_colliders_ignore_the_guess():
    """With colliders the step starts from x^n or its push-out, guess or not: the traced
    step is the same program (and without colliders it is not)."""
    start = lambda p: p.start + 0.01  # noqa: E731
    for colliders, same in (((C.Plane(normal=(0.0, 1.0, 0.0), offset=-0.5),), True), ((), False)):
        c = C.grid(3, 0.2, colliders=colliders)
        s = C.State.at_rest(c)
        plain = jax.make_jaxpr(lambda s: implicit(c, s, jnp.asarray(DT), INTEG)[:2])(s)
        guessed = jax.make_jaxpr(lambda s: implicit(c, s, jnp.asarray(DT), INTEG, start=start)[:2])(s)
        assert (str(plain) == str(guessed)) == same


def test_bad_guesses_raise(moving):
    c, _, s = moving
    with pytest.raises(ValueError, match="guess"):
        C.step(c, s, DT, INTEG, guess=s.x[:-1])
    with pytest.raises(ValueError, match="guess"):
        C.step(c, s, DT, INTEG, guess=s.x.at[0, 0].set(np.inf))
    with pytest.raises((TypeError, ValueError), match="extrapolate"):
        C.ImplicitEuler(extrapolate="yes")


@pytest.mark.slow
def test_constant_jerk_start_takes_one_newton_iteration(moving):
    """``extrapolate=2`` with PCG solved to ``cg_tol``: from the first step on, one Newton
    iteration meets float64's gradient test on the swinging grid, where the
    constant-acceleration start needs two; same converged positions."""
    c, _, s = moving
    one = dataclasses.replace(INTEG, tol=None, linear_solver=C.CG(forcing=0.0))
    two = dataclasses.replace(one, extrapolate=2)
    x1, i1 = C.rollout(c, s, DT, STEPS, one)
    x2, i2 = C.rollout(c, s, DT, STEPS, two)
    assert bool(jnp.all(i1.converged)) and bool(jnp.all(i2.converged))
    n1, n2 = np.asarray(i1.newton_iters), np.asarray(i2.newton_iters)
    assert np.all(n2 == 1) and np.all(n1 >= 2), (n1, n2)
    np.testing.assert_allclose(np.asarray(x2.x), np.asarray(x1.x), atol=1e-9)


@pytest.mark.slow
def test_constant_jerk_rollout_equals_stepping_by_hand(moving):
    c, _, s = moving
    integ = dataclasses.replace(INTEG, tol=None, linear_solver=C.CG(forcing=0.0), extrapolate=2)
    states, infos = C.rollout(c, s, DT, 4, integ)
    v1, v2 = before(c, s)
    vs, cur = [v2, v1, s.v], s
    for t in range(4):
        guess = cur.x + DT * (3 * cur.v - 3 * vs[-2] + vs[-3])
        cur, info = C.step(c, cur, DT, integ, guess=guess)
        vs.append(cur.v)
        np.testing.assert_allclose(np.asarray(cur.x), np.asarray(states.x[t]), atol=1e-12)
        assert int(info.newton_iters) == int(infos.newton_iters[t])


@pytest.mark.slow
def test_auto_takes_the_constant_jerk_start_after_a_smooth_step(moving):
    """The default ``extrapolate="auto"``: the constant-jerk start, with its first PCG solve
    aimed at the gradient test, from a bare state and after a step that converged within
    ``SMOOTH_NEWTON`` iterations: one Newton iteration per step on the swinging grid, where
    the linear start takes two."""
    c, _, s = moving
    auto = C.ImplicitEuler(linear_solver=C.CG())
    assert auto.extrapolate == "auto" and C.ImplicitEuler(linear_solver=C.CG(), extrapolate=True) == auto
    xa, ia = C.rollout(c, s, DT, STEPS, auto)
    xl, il = C.rollout(c, s, DT, STEPS, dataclasses.replace(auto, extrapolate=1))
    assert bool(jnp.all(ia.converged)) and bool(jnp.all(il.converged))
    na, nl = np.asarray(ia.newton_iters), np.asarray(il.newton_iters)
    assert np.all(na == 1) and np.all(nl >= 2), (na, nl)
    np.testing.assert_allclose(np.asarray(xa.x), np.asarray(xl.x), atol=1e-9)


@pytest.mark.parametrize("bad", [3, -1, 1.5, "yes", None])
def test_bad_extrapolation_orders_raise(bad):
    with pytest.raises(ValueError, match="extrapolate"):
        C.ImplicitEuler(extrapolate=bad)


@pytest.mark.slow
def test_residual_stop_takes_no_iteration_at_equilibrium_and_one_fewer_in_float32(moving):
    """``tol=None`` (the default) stops on the gradient test alone: a weightless cloth
    stretched by 1% between pinned borders, at rest, is converged before any iteration,
    where the lab's step test takes one; in float32
    the swinging grid's steps take one iteration fewer than with the step test, and end at
    the same positions to float32's resolution."""
    n = 6  # two rows pinned along each edge: every free particle has all its springs (bending too)
    edge = [i * (n + 1) + j for i in range(n + 1) for j in range(n + 1) if min(i, j, n - i, n - j) < 2]
    c0 = C.grid(n, 0.2, gravity=0.0, pins=edge)
    rest = np.asarray(c0.rest)
    x0 = rest.mean(axis=0) + 1.01 * (rest - rest.mean(axis=0))
    s0 = C.State(jnp.asarray(x0), jnp.zeros_like(jnp.asarray(x0)))
    _, i0 = C.step(c0, s0, DT, dataclasses.replace(INTEG, tol=None))
    _, i_tol = C.step(c0, s0, DT, INTEG)
    assert int(i0.newton_iters) == 0 and bool(i0.converged) and int(i_tol.newton_iters) >= 1
    c, _, s = moving
    c32 = jax.tree_util.tree_map(lambda a: a.astype(np.float32) if jnp.issubdtype(a.dtype, jnp.floating) else a, c)
    s32 = C.State(s.x.astype(np.float32), s.v.astype(np.float32))
    xr, ir = C.rollout(c32, s32, DT, STEPS, dataclasses.replace(INTEG, tol=None))
    xt, it = C.rollout(c32, s32, DT, STEPS, INTEG)
    assert bool(jnp.all(ir.converged)) and bool(jnp.all(it.converged))
    nr, nt = np.asarray(ir.newton_iters), np.asarray(it.newton_iters)
    assert np.all(nr[1:] <= nt[1:] - 1), (nr, nt)
    np.testing.assert_allclose(np.asarray(xr.x), np.asarray(xt.x), atol=1e-6)


AUTO = C.ImplicitEuler(linear_solver=C.CG())


@pytest.fixture(scope="module")
def chunks(moving):
    """The moving grid's next 6 steps in one rollout, and as two 3-step rollouts."""
    c, _, s = moving
    full = C.rollout(c, s, DT, 6, AUTO)
    a = C.rollout(c, s, DT, 3, AUTO)
    return c, full, a, C.State(a[0].x[-1], a[0].v[-1])


@pytest.mark.slow
def test_resumed_rollouts_equal_one_rollout(chunks):
    """Two 3-step chunks with ``resume`` take the steps of one 6-step rollout: the same
    Newton iterations and positions, to the last bits.  A bare second chunk's velocities
    before come from the forces, close but not equal (damping's frozen directions)."""
    c, (full, i_full), (a, i_a), nxt = chunks
    b, i_b = C.rollout(c, nxt, DT, 3, AUTO, resume=(a, i_a))
    bare, _ = C.rollout(c, nxt, DT, 3, AUTO)
    np.testing.assert_array_equal(np.concatenate([i_a.newton_iters, i_b.newton_iters]), np.asarray(i_full.newton_iters))
    np.testing.assert_allclose(np.concatenate([a.x, b.x]), np.asarray(full.x), rtol=0, atol=1e-15)
    assert bool(jnp.all(i_b.converged))
    assert np.max(np.abs(np.asarray(bare.x) - np.asarray(full.x[3:]))) > 1e-15
    # under jit, with the previous rollout traced
    jitted, _ = jax.jit(lambda st, r: C.rollout(c, st, DT, 3, AUTO, resume=r))(nxt, (a, i_a))
    np.testing.assert_allclose(np.asarray(jitted.x), np.asarray(b.x), rtol=0, atol=1e-12)


def test_history_before_takes_the_known_velocities_and_the_forces_for_the_rest(chunks):
    """``History.before``: a previous rollout's last velocities where known (``T = 3``: both,
    ``T = 2``: ``v^{n-1}``), the backward-Euler motion's for the rest; ``"auto"`` smooth
    for a bare state, else by the last step's diagnostics."""
    c, _, (a, _), s = chunks
    v1, v2 = before(c, s)
    conv, iters = jnp.array(True), jnp.int32(1)
    for mode in (1, 2, "auto"):
        for T, (p1, p2) in ((0, (v1, v2)), (1, (v1, v2)), (2, (a.v[-2], None)), (3, (a.v[-2], a.v[-3]))):
            h = History.before(c, s.x, s.v, DT, mode, None if T == 0 else Resume(a.v[3 - T:], conv, iters))
            np.testing.assert_allclose(np.asarray(h.v_prev), np.asarray(p1), rtol=0, atol=1e-12)
            if mode == 1:
                assert h.d_prev is None and not h.jerk
                continue
            if p2 is None:  # v^{n-2} from the forces at x^{n-1} = x - h v and v^{n-1}
                a1 = (forces(c, s.x - DT * s.v) + damping_forces(c, s.x - DT * s.v, p1)) / c.mass[:, None]
                p2 = p1 - DT * a1 * (~c.pinned)[:, None]
            np.testing.assert_allclose(np.asarray(h.d_prev), np.asarray(p1 - p2), rtol=0, atol=1e-12)
            assert bool(h.jerk)
    # the velocities before are those of the motion that led here, to within damping's frozen
    # directions: off by 0.06% and 0.11% of a step's velocity change
    dv = np.max(np.abs(np.asarray(a.v[-2] - a.v[-3])))
    assert np.max(np.abs(np.asarray(v1 - a.v[-2]))) < 1e-2 * dv and np.max(np.abs(np.asarray(v2 - a.v[-3]))) < 1e-2 * dv
    # "auto": smooth only after a converged step of at most SMOOTH_NEWTON iterations
    assert not bool(History.before(c, s.x, s.v, DT, "auto", Resume(a.v, conv, jnp.int32(SMOOTH_NEWTON + 1))).jerk)
    assert not bool(History.before(c, s.x, s.v, DT, "auto", Resume(a.v, jnp.array(False), iters)).jerk)
    assert bool(History.before(c, s.x, s.v, DT, 2, Resume(a.v, jnp.array(False), iters)).jerk)


def test_bad_resumes_raise(chunks):
    c, _, (a, i_a), s = chunks
    with pytest.raises(TypeError, match="resume"):
        C.rollout(c, s, DT, 2, AUTO, resume=a)
    with pytest.raises(TypeError, match="resume"):
        C.rollout(c, s, DT, 2, AUTO, resume=(i_a, a))
    with pytest.raises(ValueError, match="shape"):
        C.rollout(c, s, DT, 2, AUTO, resume=(C.State(a.x[0], a.v[0]), i_a))
    with pytest.raises(ValueError, match="leading"):
        C.rollout(c, s, DT, 2, AUTO, resume=(a, jax.tree_util.tree_map(lambda x: x[:2], i_a)))
    with pytest.raises(ValueError, match="finite"):
        C.rollout(c, s, DT, 2, AUTO, resume=(C.State(a.x, a.v.at[0, 0, 0].set(jnp.nan)), i_a))
    short = dataclasses.replace(i_a, memory=jax.tree_util.tree_map(lambda m: m[:2], i_a.memory))
    with pytest.raises(ValueError, match="memory"):
        C.rollout(c, s, DT, 2, AUTO, resume=(a, short))


@pytest.mark.slow
def test_resumed_batch_rollouts_equal_one_batch_rollout(moving):
    """``batch_rollout``'s ``resume``: two scenes, 3 + 3 resumed steps take the Newton
    iterations and positions of one 6-step batch rollout (a bare second chunk's differ)."""
    c, _, s = moving
    scenes = [c, C.replace(c, stiffness=1.5 * c.stiffness)]
    full, i_full = C.batch_rollout(scenes, s, DT, 6, AUTO)
    a, i_a = C.batch_rollout(scenes, s, DT, 3, AUTO)
    nxt = C.State(a.x[:, -1], a.v[:, -1])
    b, i_b = C.batch_rollout(scenes, nxt, DT, 3, AUTO, resume=(a, i_a))
    bare, _ = C.batch_rollout(scenes, nxt, DT, 3, AUTO)
    np.testing.assert_array_equal(np.concatenate([i_a.newton_iters, i_b.newton_iters], axis=1),
                                  np.asarray(i_full.newton_iters))
    np.testing.assert_allclose(np.concatenate([a.x, b.x], axis=1), np.asarray(full.x), rtol=0, atol=1e-15)
    assert bool(jnp.all(i_b.converged))
    assert np.max(np.abs(np.asarray(bare.x) - np.asarray(full.x[:, 3:]))) > 1e-15
    with pytest.raises(ValueError, match=r"shape \(2, T, 100, 3\)"):  # one rollout's outputs, not a batch's
        C.batch_rollout(scenes, nxt, DT, 3, AUTO, resume=C.rollout(c, s, DT, 3, AUTO))
    with pytest.raises(TypeError, match="batch_rollout's"):
        C.batch_rollout(scenes, nxt, DT, 3, AUTO, resume=a)
