"""Skeletons (joint trees): FK, FABRIK §4.2 and CCD with Horn's rotation, settings objects.

The humanoid checks share one compiled solve per solver (a module fixture over one batch
of 500 reachable target sets plus the special cases), and the property and gradient
tests use small trees, so compilation stays a few seconds per case.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads

from jaxsim import ik
from jaxsim._geometry import horn as _horn, quat as _quat
from jaxsim.ik._driver import inputs as _inputs, solve as _solve
from jaxsim.ik._model.skeleton import topology

from _helpers import SETTINGS, fk_reference, random_rotations

SOLVERS = ("fabrik", "ccd")


def small_tree():
    """Root, a sub-base with a one-bone and a straight two-bone branch: 5 joints, 2 leaf effectors."""
    offsets = np.array([[0, 0, 0], [0, 1.0, 0], [0.6, 0.3, 0.1], [-0.5, 0.3, 0.0], [-0.25, 0.15, 0.0]])
    return ik.Skeleton(parents=(-1, 0, 1, 1, 3), offsets=offsets)


# ---- the Skeleton type ----

@pytest.mark.parametrize("parents, offsets, match", [
    ((-1, 0), np.zeros((3, 3)) + 1, "shape"),
    ((-1, 0, 2), np.ones((3, 3)), "out of order"),
    ((-1, 0, 7), np.ones((3, 3)), "out of order or out of range"),
    ((-1, -1, 0), np.ones((3, 3)), "second root"),
    ((0, 0, 1), np.ones((3, 3)), "root"),
    ((-1, 0, 1), np.array([[0, 0, 0], [0, 1, 0], [0, np.nan, 0.0]]), "finite"),
    ((-1,), np.ones((1, 3)), "at least 2"),
])
def test_skeleton_rejects_bad_input(parents, offsets, match):
    with pytest.raises(ValueError, match=match):
        ik.Skeleton(parents=parents, offsets=offsets)


def test_skeleton_names_and_effector_checks():
    with pytest.raises(ValueError, match="names"):
        ik.Skeleton(parents=(-1, 0), offsets=np.ones((2, 3)), names=("a",))
    with pytest.raises(ValueError, match="distinct"):
        ik.Skeleton(parents=(-1, 0), offsets=np.ones((2, 3)), names=("a", "a"))
    H = ik.humanoid(limits=False)
    assert H.num_joints == 24 and H.index("l_hand") == 10 and H.parents[H.index("r_knee")] == H.index("r_hip")
    t = np.zeros((1, 3))
    for eff, match in (((24,), "out of range"), (("nose",), "no joint"), ((3, 3), "distinct"), ((), "at least")):
        with pytest.raises(ValueError, match=match):
            ik.fabrik(H, np.zeros((max(len(eff), 1), 3)), effectors=eff)
    with pytest.raises(ValueError, match=r"\(\.\.\., 2, 3\)"):
        ik.fabrik(H, t, effectors=("l_hand", "r_hand"))
    with pytest.raises(ValueError, match="weights must be > 0"):
        ik.ccd(H, t, effectors=("l_hand",), weights=[0.0])
    with pytest.raises(TypeError, match="Skeleton"):
        ik.fabrik(np.zeros((3, 3)), np.zeros(3))


def test_humanoid_rest_pose_and_proportions():
    H = ik.humanoid(limits=False)
    P = np.asarray(ik.fk(H).positions)
    assert P[H.index("head")][1] == pytest.approx(1.60)
    assert P[H.index("l_hand")][0] == pytest.approx(0.80) and P[H.index("r_hand")][0] == pytest.approx(-0.80)
    assert P[H.index("l_ankle")][1] == pytest.approx(0.09)
    assert H.leaves == tuple(H.index(n) for n in ("head", "l_hand", "r_hand", "l_toe", "r_toe"))


def test_tree_fk_matches_numpy_recursion():
    rng = np.random.default_rng(0)
    H = ik.humanoid(limits=False)
    R = random_rotations(rng, (3, H.num_joints))
    P = np.asarray(ik.fk(H, R).positions)
    for b in range(3):
        np.testing.assert_allclose(P[b], fk_reference(H.parents, np.asarray(H.offsets), R[b]), atol=1e-12)


# ---- chains are skeletons ----

@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), kind=st.sampled_from(SOLVERS), unroll=st.booleans())
@pytest.mark.slow
def test_lean_chain_kernel_equals_the_tree_kernel_on_a_chain(seed, kind, unroll):
    """A chain solved for its end takes the lean chain kernel, rolled or unrolled; the tree
    kernel, run on the same problem, gives the same poses, errors and counts (the lean
    kernel is a specialisation of the same algorithm).  Random 5-joint chains, 16 targets
    by FK of random poses, float64."""
    rng = np.random.default_rng(seed)
    chain = ik.Chain(rng.normal(size=(5, 3)) * rng.uniform(0.3, 2.0, size=(5, 1)))
    assert chain.is_chain and isinstance(chain, ik.Skeleton)
    t = np.asarray(ik.fk(chain, random_rotations(rng, (16, 5), 1.5)).positions)[:, -1:]
    settings_ = ik.FABRIK(60, 1e-6) if kind == "fabrik" else ik.CCD(60, 1e-6)
    a = ik.solve(chain, t, solver=dataclasses.replace(settings_, unroll=unroll))
    inp = _inputs.check_inputs(chain, t)
    topo = topology(chain.parents, inp.effectors)
    assert _solve.lean_chain(settings_, topo, None, None)
    b = _solve._run(settings_, chain, inp, topo, None, False, trace=False, unroll=None, early_exit=False, stop=False)
    scale = float(chain.reach)
    np.testing.assert_allclose(b.positions, a.positions, atol=1e-9 * scale)
    np.testing.assert_allclose(b.rotations, a.rotations, atol=1e-9)
    np.testing.assert_allclose(b.error, a.error, atol=1e-9 * scale)
    assert a.error.shape == b.error.shape == (16, 1)
    np.testing.assert_array_equal(b.iterations, a.iterations)


# ---- Horn's rotation ----

@pytest.mark.slow
def test_horn_recovers_a_rotation_and_reduces_to_the_shortest_arc():
    rng = np.random.default_rng(3)
    best = jax.jit(_horn.best_rotation)
    for _ in range(5):
        q = random_rotations(rng, ())
        q = q * np.sign(q[0])
        a = [tuple(jnp.asarray(x) for x in rng.normal(size=3)) for _ in range(4)]
        b = [_quat.rotate(tuple(jnp.asarray(x) for x in q), v) for v in a]
        np.testing.assert_allclose(np.array(best(a, b, [1.0, 2.0, 0.5, 1.0])), q, atol=1e-10)
        a1, b1 = (tuple(jnp.asarray(x) for x in rng.normal(size=3)) for _ in range(2))
        np.testing.assert_allclose(np.array(best([a1], [b1], [1.0])),
                                   np.array(_quat.from_two_vectors(a1, b1)), atol=1e-10)
    zero = tuple(jnp.zeros(()) for _ in range(3))
    np.testing.assert_array_equal(np.array(_horn.best_rotation([zero], [zero], [1.0])), [1, 0, 0, 0])
    g = jax.grad(lambda v: sum(_horn.best_rotation([tuple(v)], [zero], [1.0])))(jnp.ones(3))
    assert np.all(np.isfinite(g))


# ---- the humanoid: one batch, one compile per solver ----

def humanoid_batch():
    """500 reachable target sets (FK of random poses), 2 conflicting ones, and 2 special ones."""
    rng = np.random.default_rng(4)
    H = ik.humanoid(limits=False)
    eff = tuple(H.index(n) for n in ik.HUMANOID_EFFECTORS)
    reach = np.asarray(ik.fk(H, random_rotations(rng, (500, H.num_joints))).positions)[:, eff]
    conflict = np.array([[[5.0, 1.4, 0], [5.0, 1.4, 0.1], [0.09, 0.09, 0], [-0.09, 0.09, 0]],
                         [[3.0, 1.4, 0], [-3.0, 1.4, 0], [0.09, 0.09, 0], [-0.09, 0.09, 0]]])
    rest = np.asarray(ik.fk(H).positions)
    special = np.stack([rest[list(eff)] for _ in range(2)])
    special[0, 0] = rest[H.index("spine3")]                 # a hand target on its sub-base
    special[1, 2] = rest[H.index("l_hip")] + [0, -0.5, 0]  # on the straight leg's line
    return H, eff, np.concatenate([reach, conflict, special])


#: The share of the 500 reachable sets each solver must bring within 1e-4 in 100 sweeps.
RATES = {"fabrik": 0.95, "ccd": 0.5}


@pytest.mark.slow
@pytest.mark.parametrize("kind", SOLVERS)
def test_humanoid(kind):
    H, eff, targets = humanoid_batch()
    r = ik.solve(H, targets, solver=kind, effectors=eff, max_iters=100, tol=1e-4)
    # reachable sets
    conv = np.asarray(r.converged[:500])
    assert conv.mean() >= RATES[kind], (kind, conv.mean(), float(r.iterations[:500].mean()))
    assert np.all(np.asarray(r.error[:500][conv]) <= 1e-4)
    # invariants: finite, bone lengths, root fixed, FK-consistent, joints off every effector path untouched
    P = np.asarray(r.positions)
    assert np.all(np.isfinite(P)) and np.all(np.isfinite(np.asarray(r.rotations)))
    off = np.asarray(H.offsets)
    for i, p in enumerate(H.parents[1:], start=1):
        np.testing.assert_allclose(np.linalg.norm(P[:, i] - P[:, p], axis=-1), np.linalg.norm(off[i]), atol=1e-10)
    np.testing.assert_array_equal(P[:, 0], np.broadcast_to(off[0], P[:, 0].shape))
    np.testing.assert_allclose(np.asarray(ik.fk(H, r.rotations).positions), P, atol=1e-10)
    still = [j for j in range(H.num_joints) if j not in topology(H.parents, eff).moving]
    assert H.index("head") in still and H.index("l_toe") in still
    np.testing.assert_array_equal(np.asarray(r.rotations)[:, still],
                                  np.broadcast_to(np.asarray(H.rest_rotations())[still], (len(P), len(still), 4)))
    assert r.error.shape == (len(targets), 4) and r.reachable.shape == (len(targets), 4)
    # conflicting targets: finite, not converged, the error per effector
    err = np.asarray(r.error[500:502])
    assert np.all(np.isfinite(err)) and not np.any(np.asarray(r.converged[500:502]))
    assert np.all(err[:, :2] > 1.0)  # both hands are far out of reach
    assert not np.asarray(r.reachable[500, 0]) and np.asarray(r.reachable[500, 2])
    # a hand target on its own sub-base: solved; a foot target on its straight leg's line:
    # the leg is bent off the line (FABRIK §5.4) and the foot reaches it
    assert bool(r.converged[502]), np.asarray(r.error[502])
    assert float(r.error[503, 2]) <= 1e-4, np.asarray(r.error[503])


@pytest.mark.slow
@given(data=st.data())
@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_random_tree_properties(data):
    J = data.draw(st.integers(3, 6))
    parents = (-1,) + tuple(data.draw(st.integers(0, i - 1)) for i in range(1, J))
    seed = data.draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    offsets = rng.normal(size=(J, 3))
    sk = ik.Skeleton(parents=parents, offsets=offsets)
    eff = tuple(sorted(set(data.draw(st.lists(st.integers(1, J - 1), min_size=1, max_size=3)))))
    if sk.is_chain and eff == (J - 1,):
        eff = (J - 2, J - 1) if J > 2 else eff
    reach = data.draw(st.booleans())
    R = random_rotations(rng, (J,))
    t = np.asarray(ik.fk(sk, R).positions)[list(eff)] if reach else rng.normal(size=(len(eff), 3)) * 2
    start = random_rotations(rng, (J,), 0.5)
    moving = topology(parents, eff).moving
    for kind in SOLVERS:
        r = ik.solve(sk, t, solver=SETTINGS[kind](20, 1e-6, trace=True), rotations=start, effectors=eff)
        P = np.asarray(r.positions)
        assert np.all(np.isfinite(P)) and np.all(np.isfinite(np.asarray(r.error)))
        for i, p in enumerate(parents[1:], start=1):
            assert np.linalg.norm(P[i] - P[p]) == pytest.approx(np.linalg.norm(offsets[i]), abs=1e-10)
        np.testing.assert_array_equal(P[0], offsets[0])
        np.testing.assert_allclose(np.asarray(ik.fk(sk, r.rotations).positions), P, atol=1e-10)
        for j in range(J):
            if j not in moving:
                np.testing.assert_allclose(np.asarray(r.rotations[j]), start[j] / np.linalg.norm(start[j]), atol=1e-15)
        # honest counts: the sweep that stopped is the first within tol
        k, tr = int(r.iterations), np.asarray(r.trace)
        if bool(r.converged) and k > 0:
            assert tr[k - 1] <= 1e-6 and (k == 1 or tr[k - 2] > 1e-6)
        if not bool(r.converged):
            assert k == 20


# ---- transformations ----

@pytest.mark.slow
@pytest.mark.parametrize("kind", SOLVERS)
def test_tree_jit_equals_eager_and_vmap_equals_loop(kind):
    sk = small_tree()
    rng = np.random.default_rng(5)
    t = np.asarray(ik.fk(sk, random_rotations(rng, (4, 5), 1.0)).positions)[:, [2, 4]]
    f = lambda tt: ik.solve(sk, tt, solver=kind, effectors=(2, 4), max_iters=30, tol=1e-6)  # noqa: E731
    eager = f(t)
    jitted = jax.jit(f)(t)
    vm = jax.vmap(f)(t)
    loop = [f(t[b]) for b in range(4)]
    for field in ("rotations", "positions", "error", "iterations"):
        np.testing.assert_allclose(getattr(jitted, field), getattr(eager, field), atol=1e-12)
        np.testing.assert_allclose(getattr(vm, field), np.stack([getattr(x, field) for x in loop]), atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("kind", SOLVERS)
def test_tree_gradients(kind):
    """Effector positions w.r.t. the targets and the offsets, through the sweeps."""
    sk = small_tree()
    rng = np.random.default_rng(6)
    t = np.asarray(ik.fk(sk, random_rotations(rng, (5,), 1.0)).positions)[[2, 4]] + 0.05

    def effs(tt, off):
        r = ik.solve(ik.Skeleton(parents=sk.parents, offsets=off), tt, solver=kind, effectors=(2, 4),
                     max_iters=3, tol=0.0)
        return r.positions[jnp.array([2, 4])]

    check_grads(effs, (jnp.asarray(t), sk.offsets), order=1, modes=("rev",), atol=1e-5, rtol=1e-5)


@pytest.mark.slow
def test_tree_implicit_diff():
    sk = small_tree()
    rng = np.random.default_rng(7)
    t = jnp.asarray(np.asarray(ik.fk(sk, random_rotations(rng, (5,), 1.0)).positions)[[2, 4]])

    def effs(tt):
        r = ik.solve(sk, tt, solver=ik.FABRIK(300, 1e-8, implicit_diff=True), effectors=(2, 4))
        return r.positions[jnp.array([2, 4])], r.converged

    Jm, converged = jax.jacfwd(effs, has_aux=True)(t)
    assert bool(converged)
    np.testing.assert_allclose(Jm.reshape(6, 6), np.eye(6), atol=1e-6)  # reached targets follow their targets


@pytest.mark.slow
@pytest.mark.parametrize("kind", SOLVERS)
def test_no_nan_on_sub_base_and_straight_branch(kind):
    sk = small_tree()
    rest = np.asarray(ik.fk(sk).positions)
    line = rest[4] - rest[1]
    cases = [np.stack([rest[1], rest[4]]),                     # a target on the sub-base
             np.stack([rest[2], rest[1] + 3.0 * line]),        # on the straight branch's line, out of reach
             np.stack([rest[2], rest[1] + 0.5 * line])]        # on the line, inside reach: the branch must bend

    def loss(tt):
        r = ik.solve(sk, tt, solver=kind, effectors=(2, 4), max_iters=10, tol=0.0)
        return jnp.sum(r.positions ** 2) + jnp.sum(r.error), r.error

    for t in cases:
        (v, err), g = jax.value_and_grad(loss, has_aux=True)(jnp.asarray(t))
        assert np.isfinite(v) and np.all(np.isfinite(g))
    assert float(err[1]) < 0.2  # the bent branch leaves the line (0.43 away if it stayed straight)


# ---- settings objects and tracking ----

def test_settings_objects():
    s = ik.FABRIK(max_iters=20, tol=1e-5)
    assert hash(s) == hash(ik.FABRIK(max_iters=20, tol=1e-5)) and s != ik.CCD(max_iters=20, tol=1e-5)
    with pytest.raises(Exception):
        s.tol = 1.0
    for bad in (dict(max_iters=0), dict(tol=-1.0), dict(max_iters=1.5)):
        with pytest.raises(ValueError):
            ik.CCD(**bad)
    chain, t = ik.lab_arm(), np.array([[[0.5, 0.5, 0.3]], [[1.0, 1.0, 0.0]]])
    a = ik.solve(chain, t, solver=ik.CCD(max_iters=7, tol=1e-5))
    b = ik.solve(chain, t, solver="ccd", max_iters=7, tol=1e-5)
    np.testing.assert_array_equal(a.rotations, b.rotations)
    with pytest.raises(ValueError, match="settings object"):
        ik.solve(chain, t, solver=ik.CCD(), tol=1e-3)
    with pytest.raises(ValueError, match="solver must be"):
        ik.solve(chain, t, solver="newton")


@pytest.mark.parametrize("kind", SOLVERS)
@pytest.mark.slow
def test_track_on_a_tree(kind):
    sk = small_tree()
    s = np.linspace(0, 1, 6)[:, None]
    rest = np.asarray(ik.fk(sk).positions)
    targets = np.stack([rest[2] + s * [0.0, -0.3, 0.2], rest[4] + s * [0.1, -0.2, 0.1]], axis=1)
    r = ik.track(sk, targets, solver=kind, effectors=(2, 4), tol=1e-5)
    assert r.rotations.shape == (6, 5, 4) and r.error.shape == (6, 2) and r.trace.shape == (6, 100)
    assert np.all(np.asarray(r.converged))
    bad = targets.copy()
    bad[2, 0, 0] = np.nan
    rb = jax.jit(lambda tt: ik.track(sk, tt, solver=kind, effectors=(2, 4), tol=1e-6))(bad)
    assert np.isinf(rb.error[2]).all() and not bool(rb.converged[2]) and np.all(np.isfinite(rb.positions))
