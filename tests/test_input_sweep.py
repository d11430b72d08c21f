"""Bad and extreme inputs on the skeleton, limits, LM, contact, mesh and CLI features.

Each case once gave a silent wrong result, an obscure error, or accepted bad input.  The
silent ones are checked against an independent computation: per-scene rollouts for a
batch, finite differences for LM's gradient, the start pose's error for FABRIK.
"""

import math
import os
import signal
import time
from decimal import Decimal
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import cloth, ik, viz
from jaxsim._cli import _out

from _helpers import SETTINGS, limited_tree, random_rotations


# ---- silent wrong results ----

def _sphere_drop(k, radius=0.25, friction=0.3):
    return cloth.grid(4, 0.15, origin=(-0.3, 0.6, -0.3), mass=1e-2, stiffness=k, gravity=9.8, pins=[],
                      colliders=(cloth.Sphere(np.array([0, 0.3, 0.0]), radius, friction=friction),))


@pytest.mark.slow
def test_batch_rollout_keeps_colliders_and_equals_per_scene_rollouts():
    scenes = [_sphere_drop(30.0), _sphere_drop(60.0, radius=0.22)]
    s0 = cloth.State.at_rest(scenes[0])
    stacked = cloth.stack_scenes(scenes)
    assert len(stacked.colliders) == 1 and np.shape(stacked.colliders[0].radius) == (2,)
    assert np.shape(stacked.contact_gap) == (2,)
    states, infos = cloth.batch_rollout(scenes, s0, 1 / 60, 25)
    for b, sc in enumerate(scenes):
        ref, ref_info = cloth.rollout(sc, s0, 1 / 60, 25)
        np.testing.assert_allclose(np.asarray(states.x[b]), np.asarray(ref.x), atol=1e-9)
        np.testing.assert_array_equal(np.asarray(infos.newton_iters[b]), np.asarray(ref_info.newton_iters))
        c = sc.colliders[0]
        gap = np.linalg.norm(np.asarray(states.x[b]) - np.asarray(c.center), axis=-1) - float(c.radius)
        assert gap.min() > 0  # on the sphere, not through it
        assert np.all(np.asarray(infos.converged[b]))


def test_stack_scenes_rejects_different_colliders():
    free = cloth.grid(4, 0.15, origin=(-0.3, 0.6, -0.3), pins=[])
    with pytest.raises(ValueError, match="same colliders"):
        cloth.stack_scenes([_sphere_drop(30.0), free])
    with pytest.raises(ValueError, match="same colliders"):
        cloth.stack_scenes([_sphere_drop(30.0), _sphere_drop(30.0, friction=0.0)])  # friction compiled out in one
    plane = cloth.replace(free, colliders=(cloth.Plane((0, 1.0, 0), 0.0),))
    with pytest.raises(ValueError, match="same colliders"):
        cloth.stack_scenes([_sphere_drop(30.0), cloth.replace(plane, colliders=(cloth.Plane((0, 1.0, 0), 0.0, 0.3),))])


def test_batch_rollout_checks_each_scene_state_against_its_colliders():
    scenes = [_sphere_drop(30.0), _sphere_drop(30.0)]
    x = np.stack([np.asarray(scenes[0].rest)] * 2)
    x[1, 5] = [0.0, 0.3, 0.0]  # scene 1's particle 5 inside its sphere
    with pytest.raises(ValueError, match="scene 1.*inside"):
        cloth.batch_rollout(scenes, cloth.State(x, np.zeros_like(x)), 1 / 60, 2)
    with pytest.raises(ValueError, match="ImplicitEuler"):
        cloth.batch_rollout(cloth.stack_scenes(scenes), cloth.State.at_rest(scenes[0]), 1 / 60, 2,
                            cloth.ExplicitEuler())


@pytest.mark.slow
def test_collider_path_of_another_kind_is_refused():
    sc = _sphere_drop(30.0)
    s0 = cloth.State.at_rest(sc)
    plane_path = cloth.Plane(normal=np.tile([0, 1.0, 0], (5, 1)), offset=np.full(5, 0.2), friction=np.full(5, 0.3))
    with pytest.raises(ValueError, match="Plane.*Sphere"):
        cloth.rollout(sc, s0, 1 / 60, 5, colliders=(plane_path,))
    path = cloth.Sphere(np.tile([0, 0.3, 0.0], (5, 1)), np.full(5, 0.25), np.full(5, 0.3))
    bare, _ = cloth.rollout(sc, s0, 1 / 60, 5, colliders=path)  # a bare collider, as the scene takes one
    tup, _ = cloth.rollout(sc, s0, 1 / 60, 5, colliders=(path,))
    np.testing.assert_array_equal(np.asarray(bare.x), np.asarray(tup.x))
    with pytest.raises(ValueError, match="tuple of cloth.Plane"):
        cloth.rollout(sc, s0, 1 / 60, 5, colliders=("sphere",))


@pytest.fixture(scope="module")
def lm_chain():
    return ik.straight_chain([1.0, 1.0])


@pytest.mark.slow
def test_lm_gradient_matches_finite_differences_at_a_straight_chain(lm_chain):
    """Beyond reach on the chain's own line LM used to return an exactly zero gradient.

    The solution is the straight chain pointing at the target: joint ``j`` at
    ``r_j t / |t|``, so ``d sum(positions) / d t_x = (0 + 1 + 2) / |t|`` at ``t = (0, 0, 2.6)``."""
    f = jax.jit(lambda t: ik.solve(lm_chain, t, solver="lm").positions.sum())
    t0 = jnp.array([0.0, 0.0, 2.6])
    g = np.asarray(jax.grad(f)(t0))
    np.testing.assert_allclose(g, [3 / 2.6, 3 / 2.6, 0.0], atol=1e-6)
    eps = 1e-4
    fd = np.array([(f(t0 + eps * e) - f(t0 - eps * e)) / (2 * eps) for e in jnp.eye(3)])
    np.testing.assert_allclose(g, fd, atol=1e-2)  # FD through a solve stopped at tol 1e-4
    end = jax.jacrev(lambda t: ik.solve(lm_chain, t, solver="lm").positions[-1])(jnp.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(np.asarray(end), np.eye(3), atol=1e-3)  # within reach the end follows the target


@pytest.mark.slow
def test_lm_bends_a_collinear_chain(lm_chain):
    """On the chain's line at half reach, LM used to stay straight with error 1.0."""
    for solver in ("lm", "fabrik", "ccd"):
        r = ik.solve(lm_chain, jnp.array([0.0, 0.0, 1.0]), solver=solver)
        assert bool(r.converged) and float(r.error[0]) <= 1e-4, solver


@pytest.mark.slow
def test_fabrik_with_limits_never_returns_a_pose_worse_than_its_start():
    """Projected onto the limits, FABRIK's sweeps can undo their progress: the result is
    the best pose visited, never one worse than the start."""
    rng = np.random.default_rng(0)
    rises = 0
    for trial in range(4):
        sk = limited_tree(rng)
        start = ik.project_limits(sk, random_rotations(rng, (64, 6), 1.5))
        t = rng.normal(size=(64, 2, 3))
        e0 = np.max(np.linalg.norm(np.asarray(ik.fk(sk, start).positions)[:, [3, 5]] - t, axis=-1), -1)
        for kind in ("fabrik", "ccd"):
            r = ik.solve(sk, t, solver=SETTINGS[kind](30, 1e-5, trace=True), rotations=start, effectors=(3, 5))
            e = np.max(np.asarray(r.error), -1)
            assert np.all(e <= e0 + 1e-12), (trial, kind, float(np.max(e - e0)))
            rises += int(np.sum(np.asarray(r.trace)[:, -1] > e0 + 1e-9))  # the last sweep's pose was worse
            assert np.all(np.asarray(r.iterations) <= 30)
    assert rises > 0  # the case is real: some last sweeps ended worse than their start


# ---- obscure errors, now clear ----

def test_colliders_take_array_likes_and_store_arrays():
    s = cloth.Sphere(center=(0.0, 0.5, 0.0), radius=0.2, friction=0.1)
    c = cloth.Capsule(a=(0, 0.5, 0), b=[0.5, 0.5, 0], radius=0.1)
    assert all(isinstance(a, np.ndarray) for a in (s.center, s.radius, c.a, c.b, c.radius))
    sc = cloth.grid(4, 0.1, colliders=(s, c))
    np.testing.assert_allclose(np.asarray(sc.colliders[0].center), [0, 0.5, 0])


@pytest.mark.slow
def test_root_joint_as_an_effector():
    sk = limited_tree(np.random.default_rng(1))
    H = ik.humanoid()
    t = np.asarray(ik.fk(H).positions)[[H.index("pelvis"), H.index("l_hand")]] + [0, 0, 0.05]
    for kind in ("fabrik", "ccd", "lm"):
        r = ik.solve(sk, np.zeros((2, 3)), solver=kind, effectors=(0, 3), max_iters=5)
        assert float(r.error[0]) == 0.0 and np.isfinite(np.asarray(r.error)).all()
    # the humanoid case of the sweep; FABRIK and CCD shared the crash (the start's bending)
    r = ik.solve(H, t, solver="fabrik", effectors=("pelvis", "l_hand"), max_iters=3)
    assert r.error.shape == (2,) and abs(float(r.error[0]) - 0.05) < 1e-6  # the root cannot move


def test_traced_tol():
    ch = ik.straight_chain([1.0, 1.0])
    t = jnp.array([0.5, 0.0, 1.5])
    err = jax.jit(lambda tol: ik.solve(ch, t, tol=tol).error)(1e-3)
    assert err.shape == (1,) and float(err[0]) <= 1e-3
    assert float(jax.jit(lambda tol: ik.solve(ch, t, solver=ik.FABRIK(tol=tol)).error)(1e-3)[0]) <= 1e-3


def test_float32_big_sphere_is_not_reported_inside():
    sphere = cloth.Sphere((0.0, -1e9, 0.0), 1e9)
    sc = cloth.grid(4, 0.1, origin=(0, 0.05, 0), dtype=np.float32, colliders=(sphere,))  # 5 cm above its top
    assert sc.dtype == np.float32
    with pytest.raises(ValueError, match="inside"):
        cloth.grid(4, 0.1, origin=(0, -0.05, 0), dtype=np.float32, colliders=(sphere,))


def test_clear_messages():
    with pytest.raises(ValueError, match="int32"):
        ik.humanoid(dtype=np.int32)
    with pytest.raises(ValueError, match="rings"):
        cloth.disk(rings=0)
    with pytest.raises(ValueError, match="radius"):
        cloth.disk(radius=-1)
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0.0]])
    with pytest.raises(ValueError, match="folds flat"):  # vertex 3 on vertex 0, across edge 1-2
        cloth.from_mesh(V, np.array([[0, 1, 2], [3, 2, 1]]))
    with pytest.raises(ValueError, match="NaN"):
        viz.plot_surface(np.full((3, 3), np.nan), [[0, 1, 2]])
    batched = cloth.Sphere(np.zeros((2, 3)), np.ones(2))
    with pytest.raises(ValueError, match="one scene's"):
        viz.plot_surface(np.eye(3), [[0, 1, 2]], colliders=(batched,))


def test_obj_with_latin1_comment(tmp_path):
    p = tmp_path / "m.obj"
    p.write_bytes(b"# caf\xe9 latin-1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    V, T = cloth.read_obj(p)
    assert V.shape == (3, 3) and T.tolist() == [[0, 1, 2]]


@pytest.mark.slow
def test_grad_with_early_exit_names_it():
    ch = ik.straight_chain([1.0, 1.0])
    f = lambda t: ik.solve(ch, t, solver=ik.FABRIK(early_exit=True)).positions.sum()  # noqa: E731
    with pytest.raises(ValueError, match="early_exit"):
        jax.grad(f)(jnp.array([0.5, 0.0, 1.5]))
    jax.jvp(f, (jnp.array([0.5, 0.0, 1.5]),), (jnp.ones(3),))  # forward mode works
    g = jax.grad(lambda t: ik.solve(ch, t, solver=ik.FABRIK(early_exit=True, implicit_diff=True)).positions.sum())
    assert np.all(np.isfinite(np.asarray(g(jnp.array([0.5, 0.0, 1.5])))))


# ---- bad input, now refused ----

@pytest.mark.parametrize("make", [
    lambda: cloth.Plane(normal=(0, 1, 0), offset="0"),
    lambda: cloth.Plane(normal=(0, 0, 0), offset=0.0),
    lambda: cloth.Sphere((0, 0, 0), radius=-1.0),
    lambda: cloth.Sphere((0, 0, 0), radius=0.5, friction=None),
    lambda: cloth.Sphere((0, 0, 0), radius=Fraction(1, 2)),
    lambda: cloth.Sphere((0, 0, 0), radius=Decimal("0.5")),
    lambda: cloth.Sphere((0, 0, 0), radius=True),
    lambda: cloth.Sphere(None, radius=0.5),
    lambda: cloth.Capsule("a", (0, 0, 0), 0.1),
    lambda: cloth.grid(4, 0.1, colliders=(cloth.Sphere((0, 0, 0), np.array([0.2])),)),
], ids=["str-offset", "zero-normal", "negative-radius", "none-friction", "fraction", "decimal", "bool", "none-center",
        "str-end", "radius-shape-1"])
def test_collider_checks_stay_on(make):
    with pytest.raises(ValueError):
        make()


def test_collider_pytrees_still_rebuild_under_transformations():
    sc = _sphere_drop(30.0)
    s = jax.tree_util.tree_map(lambda a: a * 1, sc.colliders[0])
    assert isinstance(s, cloth.Sphere)
    jax.vmap(lambda c: c.distance(jnp.zeros(3)))(cloth.Sphere(np.zeros((2, 3)), np.ones(2), np.zeros(2)))


def test_nan_rotations_are_flagged():
    sk = limited_tree(np.random.default_rng(2))
    rot = np.tile([1.0, 0, 0, 0], (6, 1))
    rot[2] = np.nan
    v = np.asarray(ik.limit_violation(sk, rot))
    assert np.isinf(v[2]) and np.all(v[[0, 1, 3, 4, 5]] == 0)
    p = np.asarray(ik.project_limits(sk, rot))
    assert np.all(np.isnan(p[2])) and np.all(np.isfinite(p[[0, 1, 3, 4, 5]]))
    assert np.isinf(np.asarray(ik.limit_violation(ik.Skeleton((-1, 0), np.eye(3)[:2] + [0, 0, 1]), rot[1:3]))[1])


def test_skeleton_and_humanoid_arguments():
    with pytest.raises(ValueError, match="parents must be ints"):
        ik.Skeleton(parents=(-1, 0.7), offsets=np.array([[0, 0, 0], [0, 1.0, 0]]))
    with pytest.raises(ValueError, match="True or False"):
        ik.humanoid(limits="yes")


def test_obj_refuses_non_finite_and_bad_ids(tmp_path):
    p = tmp_path / "nan.obj"
    p.write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match=":2: vertex 2 has a NaN"):
        cloth.read_obj(p)
    V, T = np.eye(3), np.array([[0, 1, 2]])
    with pytest.raises(ValueError, match="NaN"):
        cloth.write_obj(tmp_path / "a.obj", np.full((3, 3), np.nan), T)
    with pytest.raises(ValueError, match="integer"):
        cloth.write_obj(tmp_path / "a.obj", V, np.array([[0.0, 1.0, 2.7]]))
    with pytest.raises(ValueError, match="stem"):
        cloth.write_obj_sequence(tmp_path / "seq", V[None], T, stem="../x")
    assert not (tmp_path / "x_0000.obj").exists()


def test_mesh_builders_refuse_empty_or_negative_sizes():
    for n in (0, -2):
        with pytest.raises(ValueError, match="grid_triangles"):
            cloth.grid_triangles(n)
    with pytest.raises(ValueError, match="radius"):
        cloth.disk(radius=-1)


def test_grid_takes_contact_gap():
    sc = cloth.grid(4, 0.1, contact_gap=0.004, colliders=(cloth.Plane((0, 1.0, 0), 0.0),))
    assert float(sc.contact_gap) == pytest.approx(0.004)
    with pytest.raises(ValueError, match="contact_gap"):
        cloth.grid(4, 0.1, contact_gap=-1.0)


# ---- the CLI's output folder ----

def test_forced_run_names_and_claims_what_it_overwrote(tmp_path):
    out = str(tmp_path / "o")
    os.makedirs(out)
    with open(os.path.join(out, "summary.md"), "w") as f:
        f.write("my notes")
    with open(os.path.join(out, "keep.txt"), "w") as f:
        f.write("mine")
    before = _out.prepare(out, "demo", force=True)
    time.sleep(0.01)
    with open(os.path.join(out, "summary.md"), "w") as f:  # the run rewrites summary.md
        f.write("# jaxsim demo summary")
    assert _out.record(out, "demo", before) == ["summary.md"]
    with pytest.raises(_out.CLIError, match="keep.txt"):  # left alone: still the user's
        _out.prepare(out, "demo", force=False)
    os.remove(os.path.join(out, "keep.txt"))
    _out.prepare(out, "demo", force=False)  # the next normal run accepts its own output


class _InterruptedInCallback:
    def __del__(self):  # Python prints and drops what a finaliser raises, as in JAX's gc callback
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)


@pytest.mark.parametrize("where", ["in the run", "in a finaliser"])
def test_interrupted_demo_does_not_block_its_rerun(tmp_path, monkeypatch, capsys, where):
    import jaxsim
    from jaxsim import __main__ as cli
    from jaxsim._cli import demo
    from jaxsim._jobs import cache

    out = tmp_path / "demo"
    sections_after = []

    def fake_run(out, fast, checkpoint):
        (tmp_path / "demo" / "ik_chain.png").write_bytes(b"png")
        checkpoint()
        if where == "in the run":
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)
        else:
            _InterruptedInCallback()  # dropped at once: its interrupt is swallowed
            checkpoint()  # the next section boundary stops the run
        sections_after.append(1)
        return 0

    monkeypatch.setattr(demo, "run", fake_run)
    monkeypatch.setattr(cache, "enable_compilation_cache", lambda: None)
    monkeypatch.setattr(jaxsim, "retain_host_memory", lambda: None)
    handler = signal.getsignal(signal.SIGINT)
    assert cli.main(["demo", "--out", str(out)]) == 130
    assert not sections_after
    assert signal.getsignal(signal.SIGINT) is handler  # restored
    stderr = capsys.readouterr().err
    assert "interrupted" in stderr and "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1
    _out.prepare(str(out), "demo", force=False)  # what it wrote is listed as its own
    assert "ik_chain.png" in (out / ".jaxsim-demo").read_text().split()


def test_limited_tree_helper_is_limited():
    sk = limited_tree(np.random.default_rng(0))
    assert sk.limits is not None and sum(lim is not None for lim in sk.limits) >= 4
    assert math.isclose(float(jnp.max(ik.limit_violation(sk, sk.rest_rotations()))), 0.0)


@pytest.mark.parametrize("solver", ["fabrik", "lm"])
def test_nonfinite_targets_inside_jit_are_flagged_with_finite_rotations(solver):
    """Inside ``jit`` a NaN or inf target cannot raise: that set comes back at its start pose
    (finite rotations), with ``error`` inf, no iterations and not converged; the other sets
    are solved as if it were not there (it gave NaN rotations, flagged by converged only)."""
    arm = ik.lab_arm()
    good = np.asarray(arm.root) + np.array([[0.6, 0.3, 0.4], [0.5, 0.2, 0.1]])
    T = np.stack([good[0], [np.nan, 0.0, 0.0], good[1], [0.0, np.inf, 0.0]])
    f = jax.jit(lambda t: ik.solve(arm, t, solver=solver))
    r = f(jnp.asarray(T))
    ref = f(jnp.asarray(good))
    assert bool(jnp.all(jnp.isfinite(r.rotations))) and bool(jnp.all(jnp.isfinite(r.positions)))
    np.testing.assert_array_equal(np.asarray(r.error)[[1, 3], 0], [np.inf, np.inf])
    np.testing.assert_array_equal(np.asarray(r.iterations)[[1, 3]], [0, 0])
    assert not np.asarray(r.converged)[[1, 3]].any() and np.asarray(r.converged)[[0, 2]].all()
    np.testing.assert_allclose(np.asarray(r.rotations)[[0, 2]], np.asarray(ref.rotations), atol=1e-6)
