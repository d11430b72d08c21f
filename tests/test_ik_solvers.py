import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads

from _helpers import TOL, random_unit_quaternions
from jaxsim import curves, ik
from jaxsim.ik._solvers import fabrik as _fabrik, loop as _loop
from jaxsim.ik._model import joints as _joints

SOLVERS = {"ccd": functools.partial(ik.ccd, trace=True), "fabrik": functools.partial(ik.fabrik, trace=True)}


def bone_vectors(positions):
    return np.diff(np.asarray(positions, np.float64), axis=-2)


@pytest.mark.parametrize("solver", ["ccd", "fabrik"])
def test_reachable_target_converges(solver, dtype):
    arm = ik.Chain(np.asarray(ik.lab_arm().offsets, dtype))
    res = SOLVERS[solver](arm, np.array([0.6, 0.3, 0.4], dtype))
    assert bool(res.converged) and bool(res.reachable)
    assert 0 < int(res.iterations) < 100
    assert res.error.shape == (1,) and float(res.error[0]) <= 1e-4
    np.testing.assert_allclose(res.positions, ik.fk(arm, res.rotations).positions, atol=TOL[dtype])
    assert res.trace.shape == (100,)
    it = int(res.iterations)
    assert float(res.trace[it - 1]) <= 1e-4 and np.all(np.asarray(res.trace[it:]) == res.trace[it - 1])


@pytest.mark.parametrize("solver, iters", [("fabrik", 100), ("ccd", 3000)])
def test_unreachable_target_stretches_along_ray(solver, iters, dtype):
    arm = ik.Chain(np.asarray(ik.lab_arm().offsets, dtype))
    target = np.array([2.5, 1.0, -2.0])
    res = SOLVERS[solver](arm, target.astype(dtype), max_iters=iters, tol=1e-4)
    root = np.array([0, 1.7, 0])
    dist = np.linalg.norm(target - root)
    assert not bool(res.converged) and not bool(res.reachable)
    assert abs(float(res.error[0]) - (dist - 2.6)) <= 1e-4
    ray = (target - root) / dist
    bones = bone_vectors(res.positions)
    cosang = bones @ ray / np.linalg.norm(bones, axis=-1)
    assert np.all(np.arccos(np.clip(cosang, -1, 1)) <= 1e-3)
    if solver == "fabrik":
        assert int(res.iterations) == 1


@pytest.mark.slow
def test_fabrik_rotations_reproduce_positions(dtype):
    """The rotation rebuild: FK of the rebuilt rotations gives FABRIK's own positions."""
    rng = np.random.default_rng(0)
    for J in (3, 6, 10):
        chain = ik.Chain(rng.normal(size=(J, 3)).astype(dtype))
        local0 = random_unit_quaternions(rng, (J,)).astype(dtype)
        P0 = ik.fk(chain, local0).positions
        target = tuple(jnp.asarray(P0[-1] + 0.3 * rng.normal(size=3).astype(dtype)))
        P = [tuple(p) for p in jnp.asarray(P0)]
        for _ in range(3):
            P = _fabrik.fabrik_sweep(P, target, tuple(chain.root), chain.lengths, tuple(jnp.array([0, 0, 1], dtype)), unroll=True)
        L0 = [tuple(q) for q in jnp.asarray(local0)]
        local = _joints.stack(_fabrik.rotations_from_positions(chain.offsets, L0, P, (), unroll=True))
        P = _joints.stack(P)
        np.testing.assert_allclose(ik.fk(chain, local).positions, P, atol=TOL[dtype] * float(np.abs(P).max()) * 2)


def _np_qmul(a, b):
    aw, av, bw, bv = a[0], a[1:], b[0], b[1:]
    return np.r_[aw * bw - av @ bv, aw * bv + bw * av + np.cross(av, bv)]


def _np_rotate(q, v):
    return _np_qmul(_np_qmul(q, np.r_[0.0, v]), q * np.r_[1, -1, -1, -1])[1:]


def _np_arc(a, b):
    q = np.r_[np.linalg.norm(a) * np.linalg.norm(b) + a @ b, np.cross(a, b)]
    return q / np.linalg.norm(q)


def test_fabrik_rotation_rebuild_is_the_world_shortest_arc():
    """The rebuild in the parent's frame equals the world-frame shortest arc, joint by
    joint: ``g_i = arc(R(g_{i-1} L0_i) o_{i+1}, P_{i+1} - P_i) g_{i-1} L0_i`` and
    ``L_i = g_{i-1}^{-1} g_i`` (numpy, float64), with a start pose per element and shared."""
    rng = np.random.default_rng(5)
    J = 6
    offsets = rng.normal(size=(J, 3))
    for shared in (False, True):
        local0 = random_unit_quaternions(rng, (J,) if shared else (4, J))
        want = random_unit_quaternions(rng, (4, J))
        P = np.asarray(ik.fk(ik.Chain(offsets), want).positions)  # positions with the chain's bone lengths
        L0 = [tuple(jnp.asarray(local0[..., i, k]) for k in range(4)) for i in range(J)]
        pos = [tuple(jnp.asarray(P[:, i, k]) for k in range(3)) for i in range(J)]
        L = _fabrik.rotations_from_positions(jnp.asarray(offsets), L0, pos, (4,), unroll=True)
        L = [tuple(jnp.broadcast_to(c, (4,)) for c in q) for q in L]  # shared entries gain the batch axis
        got = np.moveaxis(np.asarray(_joints.stack(L)), -1, 0)  # (B, J, 4)
        for b in range(4):
            l0 = local0 if shared else local0[b]
            g_parent = np.r_[1.0, 0, 0, 0]
            for i in range(J - 1):
                g = _np_qmul(g_parent, l0[i])
                g = _np_qmul(_np_arc(_np_rotate(g, offsets[i + 1]), P[b, i + 1] - P[b, i]), g)
                ref = _np_qmul(g_parent * np.r_[1, -1, -1, -1], g)
                q = got[b, i]
                np.testing.assert_allclose(q * np.sign(q @ ref), ref, atol=1e-9)
                g_parent = g
            np.testing.assert_allclose(got[b, J - 1], l0[J - 1], atol=1e-12)


@pytest.mark.parametrize("unroll", [True, False])
def test_fabrik_rotation_rebuild_folds_a_bone_back(unroll):
    """Positions where a bone points exactly against its rest direction (a straight chain
    folded back on itself, in float32 and float64): the rebuilt rotations reproduce them
    (the half-turn, not the identity)."""
    for dtype in (np.float32, np.float64):
        chain = ik.straight_chain(np.ones(3, dtype), direction=(0, 1, 0))
        P = np.array([[0, 0, 0], [0, 1, 0], [0, 0, 0], [0, 1, 0]], dtype)  # bones 1 and 2 reversed, then back
        L0 = [tuple(jnp.asarray(c) for c in q) for q in np.asarray(chain.rest_rotations())]
        pos = [tuple(jnp.asarray(c) for c in p) for p in P]
        if not unroll:
            L0, pos = jnp.asarray(np.asarray(chain.rest_rotations())), jnp.asarray(P)
        L = _fabrik.rotations_from_positions(chain.offsets, L0, pos, (), unroll=unroll)
        got = np.asarray(ik.fk(chain, _joints.stack(L) if unroll else L).positions)
        np.testing.assert_allclose(got, P, atol=4 * np.finfo(dtype).eps)


@pytest.mark.slow
def test_lab_curves_float64_every_frame_converges():
    arm = ik.lab_arm()
    assert arm.offsets.dtype == np.float64
    for make in (curves.circle, curves.cardioid):
        targets = make()
        assert targets.shape == (150, 3) and np.all(targets[:, 1] == 0)
        stats = {}
        for solver in ("ccd", "fabrik"):
            res = ik.track(arm, targets[:, None], solver=solver, max_iters=100, tol=1e-4)
            assert res.error.shape == (150, 1) and res.trace.shape == (150, 100)
            assert bool(jnp.all(res.converged)), solver
            stats[solver] = float(jnp.mean(res.iterations))
        assert stats["fabrik"] < stats["ccd"]


@pytest.mark.slow
def test_track_max_step_angle_bounds_jitter(dtype):
    arm = ik.Chain(np.asarray(ik.lab_arm().offsets, dtype))
    targets = curves.cardioid()[:, None]
    free = ik.track(arm, targets, solver="fabrik")
    bound = 0.05
    clamped = ik.track(arm, targets, solver="fabrik", max_step_angle=bound)
    j_free = ik.jitter(free.rotations, arm.rest_rotations())
    j_clamped = ik.jitter(clamped.rotations, arm.rest_rotations())
    assert float(jnp.max(j_free)) > bound  # the bound is active somewhere
    assert float(jnp.max(j_clamped)) <= bound * (1 + 1e-3) + 10 * TOL[dtype]
    np.testing.assert_allclose(clamped.positions, ik.fk(arm, clamped.rotations).positions, atol=10 * TOL[dtype])


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["ccd", "fabrik"])
def test_jit_matches_eager_and_vmap_matches_loop(solver):
    arm = ik.lab_arm()
    rng = np.random.default_rng(3)
    targets = rng.uniform(-1, 1, size=(5, 3))
    f = SOLVERS[solver]
    jitted = jax.jit(lambda t: f(arm, t, max_iters=12).positions)
    with jax.disable_jit():
        eager = np.stack([f(arm, t, max_iters=12).positions for t in targets[:2]])
    np.testing.assert_allclose(np.stack([jitted(t) for t in targets[:2]]), eager, atol=1e-10)
    loop = np.stack([f(arm, t, max_iters=12).positions for t in targets])
    vm = jax.vmap(lambda t: f(arm, t, max_iters=12).positions)(targets)
    np.testing.assert_allclose(vm, loop, atol=1e-10)
    batched = ik.solve(arm, targets.reshape(5, 1, 3), solver=solver, max_iters=12)
    assert batched.positions.shape == (5, 5, 3) and batched.error.shape == (5, 1)
    np.testing.assert_allclose(batched.positions, loop, atol=1e-10)
    # vmap over initial rotations as well
    rots = random_unit_quaternions(rng, (5, 5))
    vm2 = jax.vmap(lambda t, r: f(arm, t, rotations=r, max_iters=12).positions)(targets, rots)
    loop2 = np.stack([f(arm, t, rotations=r, max_iters=12).positions for t, r in zip(targets, rots)])
    np.testing.assert_allclose(vm2, loop2, atol=1e-10)


@pytest.mark.slow
def test_unrolled_equals_rolled():
    chain = ik.straight_chain(np.linspace(0.5, 1.5, 8), direction=(0, -1, 0))
    t = np.array([1.0, -2.0, 2.0])
    for f in SOLVERS.values():
        a, b = f(chain, t, unroll=True, max_iters=30), f(chain, t, unroll=False, max_iters=30)
        np.testing.assert_allclose(a.positions, b.positions, atol=1e-9)
        assert int(a.iterations) == int(b.iterations)


@pytest.mark.parametrize("early_exit", [False, True])
@pytest.mark.parametrize("trace", [False, True])
def test_snapshot_freeze_equals_where(trace, early_exit):
    """The two ways of freezing a finished element give the same states (to rounding),
    counts and traces:
    elements done at the start, done at different sweeps (the first and the last included)
    and never done."""
    def sweep(s):
        x, y = s
        x = 0.5 * x + 0.01 * jnp.sin(y)
        return (x, y + 1.0), x * x

    x0 = jnp.array([3.0, 0.1, 1.0, 1e3, 0.5, 2.0, 0.09, 0.0])
    state0 = (x0, jnp.arange(8.0))
    done0 = jnp.array([False, True, False, False, False, False, False, True])
    err0 = jnp.abs(x0)
    out = {}
    for freeze in ("where", "snapshot"):
        out[freeze] = jax.jit(lambda s, f=freeze: _loop.masked_sweeps(
            sweep, s, err0, jnp.zeros(8, jnp.int32), done0, 0.05, max_iters=6, trace=trace,
            early_exit=early_exit, freeze=f))(state0)
    (sw, iw, tw), (ss, is_, ts) = out["where"], out["snapshot"]
    iters = np.asarray(iw)
    # first within tol at sweeps 1, 4, 5 and 6 (the last), one never, two at the start
    assert list(iters) == [6, 0, 5, 6, 4, 6, 1, 0]
    for a, b in zip(sw, ss):  # the same sweeps; XLA may round the two programs differently
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=0)
    np.testing.assert_array_equal(iw, is_)
    if trace:
        np.testing.assert_allclose(tw, ts, rtol=1e-14, atol=0)


@pytest.mark.slow
def test_batched_fabrik_frozen_at_first_sweep_within_tol(dtype):
    """The batched (unrolled, snapshot) FABRIK solve returns, for each target, the pose of
    the sweep that first met ``tol``: the same as one-target solves on the rolled loop."""
    chain = ik.Chain(np.asarray(ik.straight_chain(np.ones(5), direction=(0, 1, 0)).offsets, dtype))
    rng = np.random.default_rng(3)
    d = rng.normal(size=(300, 3))
    t = (d / np.linalg.norm(d, axis=1, keepdims=True) * 5.0 * rng.uniform(0, 1.1, (300, 1)) ** (1 / 3)).astype(dtype)
    t[0] = np.asarray(ik.fk(chain).positions)[-1]  # done before the first sweep
    batched = ik.solve(chain, t[:, None], solver=ik.FABRIK(40, 1e-3, unroll=True))
    rolled = jax.vmap(lambda x: ik.solve(chain, x, solver=ik.FABRIK(40, 1e-3, unroll=False)))(t)
    it = np.asarray(batched.iterations)
    assert it.min() == 0 and 1 < np.median(it) < 40 and it.max() == 40  # a mix of stopping sweeps
    np.testing.assert_array_equal(batched.iterations, rolled.iterations)
    np.testing.assert_allclose(batched.positions, rolled.positions, atol=TOL[np.dtype(dtype)])


# ---- hypothesis properties (float64; six-joint chains so one compilation serves all) ----

chains6 = st.lists(st.floats(0.2, 2.0), min_size=5, max_size=5)
directions = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(
    lambda v: np.linalg.norm(v) > 0.1
)


@settings(max_examples=30, deadline=None)
@given(lengths=chains6, direction=directions, frac=st.floats(0.05, 0.95), solver=st.sampled_from(["ccd", "fabrik"]))
@example(lengths=[0.25, 1.0, 1.0, 1.0, 1.0], direction=(-1.0, 0.0, 0.0), frac=0.9375, solver="ccd")
@pytest.mark.slow
def test_property_lengths_root_and_convergence(lengths, direction, frac, solver):
    """Bone lengths and the root kept, and convergence to 1e-6.  CCD converges linearly, and
    slowly on a nearly straight chain: the example (found by this test, 94% of the reach)
    takes 3,275 sweeps, 90% of the reach 1,430, 80% 68; hence CCD's budget of 5,000."""
    lengths = np.asarray(lengths)
    # a chain with a bend so the rest pose is generic
    offs = np.zeros((6, 3))
    offs[0] = [0.1, 0.2, 0.3]
    for i, L in enumerate(lengths):
        a = 0.4 * (i + 1)
        offs[i + 1] = L * np.array([np.cos(a), np.sin(a), 0.3])
        offs[i + 1] *= L / np.linalg.norm(offs[i + 1])
    chain = ik.Chain(offs)
    d = np.asarray(direction) / np.linalg.norm(direction)
    # reachable: inside the annulus [max(0, 2*max - sum), sum]
    inner = max(0.0, 2 * lengths.max() - lengths.sum())
    r = inner + frac * (lengths.sum() - inner)
    target = offs[0] + r * d
    res = SOLVERS[solver](chain, target, max_iters=5000 if solver == "ccd" else 500, tol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(bone_vectors(res.positions), axis=-1), lengths, rtol=1e-9)
    np.testing.assert_allclose(res.positions[0], offs[0], atol=1e-12)
    assert bool(res.converged), (float(res.error[0]), int(res.iterations))


# ---- gradients ----

@pytest.mark.slow
@pytest.mark.parametrize("solver", ["ccd", "fabrik"])
def test_check_grads_end_position(solver):
    arm = ik.lab_arm()
    f = SOLVERS[solver]
    rest = np.asarray(random_unit_quaternions(np.random.default_rng(5), (5,)) * 0.05 + np.array([1.0, 0, 0, 0]))
    rest = rest / np.linalg.norm(rest, axis=-1, keepdims=True)

    def end(target, offsets, rots):  # the end position and the solution's rotations
        r = f(ik.Chain(offsets), target, rotations=rots, max_iters=6, tol=0.0, trace=False)
        return jnp.concatenate([r.positions[-1], r.rotations.ravel()])

    args = (jnp.array([0.5, 0.2, 0.3]), arm.offsets, jnp.asarray(rest))
    check_grads(end, args, order=1, modes=("fwd", "rev"), atol=1e-5, rtol=1e-5, eps=1e-6)
    J = jax.jacfwd(end)(*args)
    assert np.all(np.isfinite(J))


# ---- singular and extreme cases: finite results and gradients ----

def singular_groups():
    """Cases grouped by chain size, so each group is one vmapped compilation."""
    arm = np.asarray(ik.lab_arm().offsets)
    straight = np.asarray(ik.straight_chain([1.0, 1.0, 1.0, 1.0], direction=(0, 0, 1)).offsets)
    extreme = np.asarray(ik.straight_chain([1e-3, 1e3, 1e-3, 1.0], direction=(1, 0, 0)).offsets)
    five = {
        "target_at_root": (arm, [0, 1.7, 0.0]),
        "target_at_end": (arm, [0, -0.9, 0.0]),
        "straight_line_reachable": (straight, [0, 0, 1.5]),
        "straight_line_behind": (straight, [0, 0, -1.5]),
        "straight_line_unreachable": (straight, [0, 0, 5.0]),
        "extreme_lengths": (extreme, [500.0, 300.0, 10.0]),
    }
    return {
        "five_joints": five,
        "two_joints": {"two_joints": (np.asarray(ik.straight_chain([1.0]).offsets), [0.3, 0.4, 0.0])},
        "sixty_four_joints": {"sixty_four_joints": (np.asarray(ik.straight_chain(np.full(63, 0.1), direction=(0, 1, 0)).offsets), [1.0, 2.0, 0.5])},
    }


def results_and_grads(f, offsets, targets, max_iters):
    def one(o, t):
        def loss(t, o):
            r = f(ik.Chain(o), t, max_iters=max_iters, trace=False)
            return jnp.sum(r.positions[-1]), r

        (_, res), grads = jax.value_and_grad(loss, argnums=(0, 1), has_aux=True)(t, o)
        return res, grads

    return jax.jit(jax.vmap(one))(offsets, targets)


# every group in float64; float32 on the five-joint group, which holds the symmetric poses
SINGULAR_RUNS = [(g, np.dtype(np.float64)) for g in singular_groups()] + [("five_joints", np.dtype(np.float32))]


@pytest.mark.slow
@pytest.mark.parametrize("group, dtype", SINGULAR_RUNS, ids=[f"{g}-{d.name}" for g, d in SINGULAR_RUNS])
@pytest.mark.parametrize("solver", ["ccd", "fabrik"])
def test_singular_cases_no_nan(group, solver, dtype):
    cases = singular_groups()[group]
    offsets = jnp.asarray(np.stack([c[0] for c in cases.values()]), dtype)
    targets = jnp.asarray(np.array([c[1] for c in cases.values()]), dtype)
    res, grads = results_and_grads(SOLVERS[solver], offsets, targets, 20)
    for name, leaf in zip(["rotations", "positions", "error"], [res.rotations, res.positions, res.error]):
        bad = ~np.all(np.isfinite(np.asarray(leaf, np.float64)).reshape(len(cases), -1), axis=1)
        assert not bad.any(), (name, [n for n, b in zip(cases, bad) if b])
    for g in grads:
        bad = ~np.all(np.isfinite(np.asarray(g)).reshape(len(cases), -1), axis=1)
        assert not bad.any(), ("gradient", [n for n, b in zip(cases, bad) if b])


@pytest.mark.parametrize("solver", ["ccd", "fabrik"])
def test_singular_reachable_cases_converge(solver):
    """The symmetric poses are not just finite: with the symmetry broken they converge."""
    cases = singular_groups()["five_joints"]
    names = ["target_at_root", "target_at_end", "straight_line_reachable", "straight_line_behind"]
    offsets = jnp.asarray(np.stack([cases[n][0] for n in names]))
    targets = jnp.asarray(np.array([cases[n][1] for n in names]))
    res = jax.vmap(lambda o, t: SOLVERS[solver](ik.Chain(o), t, max_iters=500, trace=False))(offsets, targets)
    assert bool(jnp.all(res.converged)), dict(zip(names, np.asarray(res.error)))


def test_bad_inputs_raise():
    arm = ik.lab_arm()
    with pytest.raises(ValueError, match="target"):
        ik.fabrik(arm, [1.0, 2.0])
    with pytest.raises(ValueError, match="finite"):
        ik.ccd(arm, [np.nan, 0, 0])
    with pytest.raises(ValueError, match="rotations"):
        ik.ccd(arm, [0, 0, 0], rotations=np.ones((4, 4)))
    with pytest.raises(ValueError, match="zero quaternion"):
        ik.ccd(arm, [0, 0, 0], rotations=np.zeros((5, 4)))
    with pytest.raises(ValueError, match="max_iters"):
        ik.fabrik(arm, [0, 0, 0], max_iters=0)
    with pytest.raises(ValueError, match="tol"):
        ik.fabrik(arm, [0, 0, 0], tol=-1.0)
    with pytest.raises(ValueError, match="solver"):
        ik.solve(arm, np.zeros((3, 1, 3)), solver="jacobian")
    with pytest.raises(ValueError, match="tol"):
        ik.track(arm, np.zeros((3, 1, 3)), tol=-1.0)
    with pytest.raises(ValueError, match="max_iters"):
        ik.track(arm, np.zeros((3, 1, 3)), max_iters=0)
