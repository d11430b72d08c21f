"""What a clip drives (``anim.resample``, ``anim.bone_points``, ``anim.body_capsules``):
against SciPy's slerp and a NumPy FK, and every bad input raising its error."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy.spatial.transform import Rotation, Slerp

from jaxsim import anim, cloth
from jaxsim._geometry import quat as Q
from _helpers import fk_reference, random_unit_quaternions, synthetic_walk

jax.config.update("jax_enable_x64", True)

WALK, _ = synthetic_walk(1.0, 1.0, 0.0, np.float64, T=31, fps=30.0)


def scipy_slerp(q0, q1, t):
    """``(..., 4)`` (w, x, y, z) SciPy's slerp of each pair at ``t``."""
    out = []
    for a, b, s in zip(q0.reshape(-1, 4), q1.reshape(-1, 4), np.broadcast_to(t, q0.shape[:-1]).reshape(-1)):
        r = Slerp([0.0, 1.0], Rotation.from_quat(np.stack([a, b])[:, [1, 2, 3, 0]], scalar_first=False))([s])
        out.append(r.as_quat()[0][[3, 0, 1, 2]])
    return np.array(out).reshape(q0.shape)


def same_rotation(a, b, atol):
    """Unit quaternions equal up to sign."""
    d = np.minimum(np.abs(a - b).max(-1), np.abs(a + b).max(-1))
    assert d.max() <= atol, d.max()


def test_slerp_against_scipy_and_nan_free_at_equal_ends():
    rng = np.random.default_rng(0)
    a, b = random_unit_quaternions(rng, (64,)), random_unit_quaternions(rng, (64,))
    b[:8] = a[:8]  # equal ends
    b[8:16] = -a[8:16] + 1e-9  # the same rotation, the other sign
    t = rng.uniform(0, 1, 64)
    got = np.asarray(Q.stack(Q.slerp(Q.unstack(jnp.asarray(a), -1), Q.unstack(jnp.asarray(b), -1), jnp.asarray(t)), -1))
    same_rotation(got, scipy_slerp(a, b, t), 1e-9)
    np.testing.assert_allclose(np.linalg.norm(got, axis=-1), 1.0, atol=1e-12)
    g = jax.grad(lambda a: jnp.sum(Q.stack(Q.slerp(Q.unstack(a, -1), Q.unstack(a, -1), 0.3), -1)))(jnp.asarray(a))
    assert bool(jnp.all(jnp.isfinite(g)))


def test_resample_hits_the_frames_and_interpolates_between_them():
    same = anim.resample(WALK, WALK.frame_time)
    assert same.num_frames == WALK.num_frames
    np.testing.assert_allclose(same.rotations, WALK.rotations, atol=1e-12)
    np.testing.assert_allclose(same.root_positions, WALK.root_positions, atol=1e-12)
    half = anim.resample(WALK, WALK.frame_time / 2, start=WALK.frame_time, duration=10 * WALK.frame_time)
    assert half.num_frames == 21 and half.frame_time == pytest.approx(WALK.frame_time / 2)
    r, p = np.asarray(WALK.rotations), np.asarray(WALK.root_positions)
    same_rotation(np.asarray(half.rotations)[1::2], scipy_slerp(r[1:11], r[2:12], 0.5), 1e-12)
    np.testing.assert_allclose(half.root_positions[1::2], (p[1:11] + p[2:12]) / 2, atol=1e-12)
    np.testing.assert_allclose(half.root_positions[::2], p[1:12], atol=1e-12)


def test_bone_points_against_numpy_fk():
    local = np.array([[0.1, 0.0, -0.05], [0.0, 0.2, 0.0]])
    pts = np.asarray(anim.bone_points(WALK, "lknee", local))
    sk = WALK.skeleton
    for t in (0, 7, 30):
        P, G = fk_reference(sk.parents, np.asarray(sk.offsets).copy(), np.asarray(WALK.rotations[t]), frames=True)
        P = P + np.asarray(WALK.root_positions[t]) - np.asarray(sk.offsets[0])
        np.testing.assert_allclose(pts[t], P[2] + local @ G[2].T, atol=1e-12)
    back = anim.bone_local(WALK, "lknee", pts[7], frame=7)
    np.testing.assert_allclose(back, local, atol=1e-12)
    on_60 = anim.bone_points(WALK, 2, local, frame_time=1 / 60)
    assert on_60.shape == (61, 2, 3)
    np.testing.assert_allclose(on_60[::2], pts, atol=1e-12)
    check_grads(lambda l: anim.bone_points(WALK, "lknee", l, frame_time=1 / 45), (jnp.asarray(local),), order=1,
                modes=("rev",))


def test_body_capsules_follow_the_bones_and_drive_a_rollout():
    caps = anim.body_capsules(WALK, {"lhip": 0.07, ("hips", "rknee"): 0.05}, friction=0.3)
    P = np.asarray(anim.positions(WALK))
    np.testing.assert_allclose(caps[0].a, P[:, 1], atol=1e-12)
    np.testing.assert_allclose(caps[0].b, P[:, 2], atol=1e-12)
    np.testing.assert_allclose(caps[1].b, P[:, 6], atol=1e-12)
    assert caps[0].radius.shape == (31,) and caps[0].frictional
    first = jax.tree.map(lambda a: a[0], caps)
    scene = cloth.grid(3, 0.1, origin=(-0.15, 1.2, -0.15), pins=[], gravity=9.8, colliders=first, dtype=np.float64)
    states, infos = cloth.rollout(scene, cloth.State.at_rest(scene), WALK.frame_time, 3,
                                  colliders=jax.tree.map(lambda a: a[1:4], caps))
    assert states.x.shape == (3, 16, 3) and bool(jnp.all(infos.stable))


@pytest.mark.parametrize("call, match", [
    (lambda: anim.resample(WALK, 0.0), "frame_time"),
    (lambda: anim.resample(WALK, 0.01, start=5.0), "start must lie within"),
    (lambda: anim.resample(WALK, 0.01, duration=2.0), "runs past the clip's end"),
    (lambda: anim.resample("walk", 0.01), "Motion"),
    (lambda: anim.bone_points(WALK, "elbow", np.zeros((1, 3))), "no joint named 'elbow'"),
    (lambda: anim.bone_points(WALK, 9, np.zeros((1, 3))), r"id in \[0, 9\)"),
    (lambda: anim.bone_points(WALK, 1, np.zeros((1, 2))), "local_points must have shape"),
    (lambda: anim.bone_points(WALK, 1, np.full((1, 3), np.nan)), "local_points must be finite"),
    (lambda: anim.body_capsules(WALK, {"hips": 0.1}), "has 2 children"),
    (lambda: anim.bone_local(WALK, 1, np.zeros((1, 3)), frame=31), "frame must be a frame index"),
    (lambda: anim.body_capsules(WALK, {"lhip": -0.1}), "radius of bone 'lhip'"),
    (lambda: anim.body_capsules(WALK, {}), "non-empty dict"),
    (lambda: anim.body_capsules(WALK, {("lhip",): 0.1}), "pair of joints"),
])
def test_bad_inputs_are_rejected(call, match):
    with pytest.raises((ValueError, TypeError), match=match):
        call()
