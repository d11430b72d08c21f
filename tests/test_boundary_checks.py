"""Bad inputs at the API boundary: each raises a clear ValueError (or is made consistent)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import cloth as C, curves, ik, optim, viz
from jaxsim.curves import _image

ARM = ik.lab_arm()
TARGETS = curves.circle()[:6, None]  # (6, 1, 3): six frames, the arm's one effector


def raises(match, fn, *args, **kw):
    with pytest.raises(ValueError, match=match):
        fn(*args, **kw)


# ---- IK ----

def test_fk_normalises_quaternions_and_keeps_bone_lengths():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(8, 5, 4))
    for scale in (3.0, 1e-30, 1e30):
        P = np.asarray(ik.fk(ARM, scale * q).positions)
        np.testing.assert_allclose(np.linalg.norm(np.diff(P, axis=-2), axis=-1), np.broadcast_to(ARM.lengths, (8, 4)),
                                   rtol=1e-12)
        np.testing.assert_allclose(P, np.asarray(ik.fk(ARM, q).positions), atol=1e-12)
    # a zero quaternion is the identity
    zero = np.zeros((5, 4))
    np.testing.assert_allclose(np.asarray(ik.fk(ARM, zero).positions), np.asarray(ik.fk(ARM).positions))
    g = jax.grad(lambda r: jnp.sum(ik.fk(ARM, r).positions))(jnp.asarray(zero))
    assert np.all(np.isfinite(np.asarray(g)))


def test_track_checks_start_rotations():
    raises("zero quaternion", ik.track, ARM, TARGETS, rotations=np.zeros((5, 4)))
    bad = np.tile([1.0, 0, 0, 0], (5, 1))
    bad[2, 1] = np.nan
    raises("rotations must be finite", ik.track, ARM, TARGETS, rotations=bad)


def test_track_under_jit_survives_a_nan_frame():
    t = np.asarray(curves.circle()[:20, None]).copy()
    t[5] = np.nan
    res = jax.jit(lambda tt: ik.track(ARM, tt))(jnp.asarray(t))
    assert np.all(np.isfinite(np.asarray(res.rotations))) and np.all(np.isfinite(np.asarray(res.positions)))
    err, conv = np.asarray(res.error), np.asarray(res.converged)
    assert np.isinf(err[5]).all() and not conv[5] and int(res.iterations[5]) == 0
    assert conv[6:].all() and np.all(err[6:] < 1e-4)  # later frames go on from the last good pose
    np.testing.assert_array_equal(np.asarray(res.rotations[5]), np.asarray(res.rotations[4]))
    assert not np.any(np.isnan(np.asarray(res.trace)))


@pytest.mark.parametrize("kw, match", [
    (dict(max_iters=True), "max_iters must be an int"),
    (dict(max_iters=2.0), "max_iters must be an int"),
    (dict(tol="0.1"), "tol must be a real number"),
    (dict(tol=-1.0), "tol must be >= 0"),
    (dict(tol=np.inf), "tol must be finite"),
    (dict(solver="newton"), "solver must be one of"),
])
def test_bad_solver_settings(kw, match):
    raises(match, ik.solve, ARM, TARGETS, **kw)
    raises(match, ik.track, ARM, TARGETS, **kw)


@pytest.mark.parametrize("settings", [ik.FABRIK, ik.CCD, ik.LevenbergMarquardt])
@pytest.mark.parametrize("kw, match", [
    (dict(trace="no"), "trace must be True or False"),
    (dict(trace=None), "trace must be True or False"),
    (dict(early_exit=1), "early_exit must be True or False"),
    (dict(implicit_diff=0), "implicit_diff must be True or False"),
])
def test_bad_settings_flags(settings, kw, match):
    raises(match, settings, **kw)
    if None not in kw.values():  # the old spelling, solve(trace=...), names the same value
        with pytest.warns(DeprecationWarning, match="moved onto the solver's settings"):
            raises(match, ik.solve, ARM, TARGETS, **kw)


def test_unroll_is_a_sweep_solvers_setting():
    raises("unroll must be True or False", ik.FABRIK, unroll="yes")
    with pytest.warns(DeprecationWarning):
        raises("unroll applies to FABRIK and CCD", ik.solve, ARM, TARGETS, solver="lm", unroll=True)


def test_numpy_ints_are_ints():
    assert ik.solve(ARM, TARGETS, max_iters=np.int64(3)).iterations.shape == (6,)
    assert C.ExplicitEuler(substeps=np.int64(3)) == C.ExplicitEuler(substeps=3)
    c = C.grid(np.int64(2))
    states, _ = C.rollout(c, C.State.at_rest(c), 1 / 60, np.int64(2), C.ExplicitEuler(substeps=np.int32(2)))
    assert states.x.shape[0] == 2
    states, _ = C.batch_rollout([c, c], C.State.at_rest(c), 1 / 60, np.int64(2), C.ExplicitEuler())
    assert states.x.shape[:2] == (2, 2)


def test_chain_checks():
    raises("direction must be a finite non-zero vector", ik.straight_chain, [1.0, 1.0], direction=(0, 0, 0))
    raises("too large for float32", ik.Chain, np.array([[0, 0, 0], [1e19, 0, 0], [1e19, 0, 0]], np.float32))
    ik.Chain(np.array([[0, 0, 0], [1e19, 0, 0], [1e19, 0, 0]], np.float64))  # fine in float64
    # one model, one validator: a tree gets the chain's checks (it used to accept these offsets)
    raises("too large for float32", ik.Skeleton, parents=(-1, 0, 0),
           offsets=np.array([[0, 0, 0], [3e19, 0, 0], [0, 3e19, 0]], np.float32))
    assert isinstance(ik.Chain(np.ones((3, 3))), ik.Skeleton) and ik.lab_arm().is_chain
    raises("float32 or float64", ik.Chain, np.array([[0, 0, 0], [1, 0, 0]], np.float16))
    raises("positive length", ik.fabrik, ik.Chain(np.array([[0, 0, 0], [1e-30, 0, 0]], np.float32)), np.ones(3))


def test_jitter_needs_frames():
    raises(r"\(T, J, 4\)", ik.jitter, np.tile([1.0, 0, 0, 0], (5, 1)))


# ---- cloth ----

@pytest.mark.parametrize("call, match", [
    (lambda: C.grid(3, dtype=np.int32), "dtype must be float32 or float64"),
    (lambda: C.grid(True), "must be an int"),
    (lambda: C.grid(2.5), "must be an int"),
    (lambda: C.grid(3, pins=[1.7]), "pin ids must be integers"),
    (lambda: C.grid(3, spacing="0.2"), "spacing must be a real number"),
    (lambda: C.ImplicitEuler(line_search="no"), "line_search must be True or False"),
    (lambda: C.ImplicitEuler(max_backtracks=-1), "max_backtracks must be an int >= 0"),
    (lambda: C.ImplicitEuler(newton_iters=True), "newton_iters must be an int"),
    (lambda: C.ImplicitEuler(tol="0.1"), "tol must be a real number"),
    (lambda: C.ImplicitEuler(rtol=-1.0), "rtol must be >= 0"),
    (lambda: C.ExplicitEuler(substeps=2.0), "substeps must be an int"),
])
def test_bad_cloth_settings(call, match):
    raises(match, call)


def test_batch_rollout_checks_stacked_scenes():
    c = C.grid(3, 0.2)
    stacked = C.stack_scenes([c, c])
    s0 = C.State.at_rest(c)
    raises("dt must be > 0", C.batch_rollout, stacked, s0, -1.0, 3)
    other = C.State.at_rest(C.grid(4, 0.2))
    raises(r"state.x must have shape \(16, 3\)", C.batch_rollout, stacked, other, 1 / 60, 3)
    raises(r"state.x must have shape", C.batch_rollout, stacked, C.State(jnp.stack([s0.x] * 3), jnp.stack([s0.v] * 3)),
           1 / 60, 3)
    bad = C.stack_scenes([c, C.replace(c, damping=0.5)])
    bad = jax.tree_util.tree_map(lambda a: a, bad)
    neg = C.replace(bad, mass=bad.mass.at[1, 3].set(-1.0))  # a batch is checked by batch_rollout
    raises("batched scene mass must be > 0", C.batch_rollout, neg, s0, 1 / 60, 3)
    raises("n_steps must be an int", C.batch_rollout, stacked, s0, 1 / 60, 3.0)
    raises("this scene is batched", C.step, stacked, s0, 1 / 60)


def test_optimiser_settings():
    raises("damping must be > 0", optim.levenberg_marquardt, lambda p: p - 1.0, jnp.zeros(2), damping=-1)
    raises("steps must be an int >= 1", optim.adam, lambda p: jnp.sum(p ** 2), jnp.zeros(2), steps=-1, lr=0.1)
    raises("lr must be > 0", optim.adam, lambda p: jnp.sum(p ** 2), jnp.zeros(2), steps=3, lr=0.0)
    raises("steps must be an int", optim.levenberg_marquardt, lambda p: p - 1.0, jnp.zeros(2), steps=1.5)


# ---- viz ----

def test_viz_checks(tmp_path):
    res = ik.track(ARM, TARGETS)
    raises("plane must be one of", viz.plot_tracking, res, TARGETS, plane="ab")
    raises("plane must be one of", viz.plot_chain, res.positions[0], plane="q")
    raises("no frames", viz.animate_tracking, ik.track(ARM, TARGETS)[:0] if False else res.__class__(
        **{k: None if v is None else v[:0] for k, v in vars(res).items()}), TARGETS[:0], str(tmp_path / "a.gif"))
    raises("frames but the result has", viz.animate_tracking, res, TARGETS[:3], str(tmp_path / "a.gif"))
    raises("fps must be > 0", viz.animate_tracking, res, TARGETS, str(tmp_path / "a.gif"), fps=0)
    c = C.grid(2, 0.2)
    raises("fps must be > 0", viz.animate_cloth, c, np.asarray(c.rest)[None], str(tmp_path / "c.gif"), fps=0)
    raises("no frames", viz.animate_cloth, c, np.zeros((0, 9, 3)), str(tmp_path / "c.gif"))
    raises(r"xs must have shape \(T, 9, 3\)", viz.animate_cloth, c, np.zeros((2, 8, 3)), str(tmp_path / "c.gif"))
    fig = viz.plot_chain(res.positions[0])
    path = viz.save(fig, str(tmp_path / "figure"))
    assert path.endswith("figure.png") and (tmp_path / "figure.png").exists()
    assert viz.save(fig, str(tmp_path / "f.pdf")).endswith("f.pdf")


# ---- from_image: nearest-start search agrees with the brute force ----

def test_nearest_start_matches_brute_force():
    rng = np.random.default_rng(3)
    for _ in range(200):
        todo = rng.random((30, 40)) > rng.uniform(0.5, 0.995)
        if not todo.any():
            continue
        deg = rng.integers(0, 4, size=todo.shape)
        pos = (int(rng.integers(0, 30)), int(rng.integers(0, 40)))
        rest = np.argwhere(todo)
        d = np.sum((rest - pos) ** 2, axis=1)
        near = rest[d == d.min()]
        e = near[deg[near[:, 0], near[:, 1]] == 1]
        want = tuple(int(v) for v in (e if len(e) else near)[0])
        assert _image._nearest_start(todo, deg, pos) == want


@pytest.mark.slow
def test_zero_start_rotation_under_jit_is_the_identity():
    """Outside jit a zero quaternion raises; inside, where nothing can raise, it is the identity."""
    raises("zero quaternion", ik.fabrik, ARM, TARGETS[0], rotations=np.zeros((5, 4)))
    for solver in (ik.fabrik, ik.ccd):
        res = jax.jit(lambda q, f=solver: f(ARM, TARGETS[0], rotations=q, max_iters=30))(jnp.zeros((5, 4)))
        ref = solver(ARM, TARGETS[0], max_iters=30)
        np.testing.assert_allclose(np.asarray(res.positions), np.asarray(ref.positions), atol=1e-12)


def test_targets_must_be_real_numbers_and_one_effector_takes_n_by_3():
    """A string or a complex array is refused, naming it (a string raised from numpy, a
    complex array lost its imaginary part); with one effector ``(N, 3)`` is N targets, and
    with several it names the shape it expected."""
    raises("targets must be real numbers, got 'abc'", ik.solve, ARM, "abc")
    raises("targets must be real numbers, got an array of complex128", ik.solve, ARM,
           np.array([0.5, 1.0, 0.2]) + 1j)
    T = np.asarray(ARM.root) + np.array([[0.6, 0.3, 0.4], [0.5, 0.2, 0.1], [1.0, -0.2, 0.3]])
    many = ik.solve(ARM, T)
    assert many.error.shape == (3, 1)
    np.testing.assert_allclose(many.rotations, ik.solve(ARM, T[:, None]).rotations, atol=0)
    H = ik.humanoid()
    raises(r"targets must have shape \(\.\.\., 4, 3\) .* give \(3, 4, 3\)", ik.solve, H, T,
           effectors=ik.HUMANOID_EFFECTORS)
