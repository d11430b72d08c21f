"""``anim.retarget``: the CMU walk onto ``ik.humanoid()`` (its limits kept), effector errors
reported, gradients through it, and bad mappings raising."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from _helpers import synthetic_walk
from jaxsim import anim, ik

MAPPING = {"l_hand": "LeftWrist", "r_hand": "RightWrist", "l_ankle": "LeftAnkle", "r_ankle": "RightAnkle"}


@pytest.mark.slow
def test_the_cmu_walk_onto_the_humanoid():
    w = anim.cmu_walk(np.float32)
    clip = anim.Motion(skeleton=w.skeleton, rotations=w.rotations[300:360], root_positions=w.root_positions[300:360],
                       frame_time=w.frame_time, channels=w.channels)
    H = ik.humanoid(np.float32)
    r = anim.retarget(clip, H, MAPPING)
    assert r.motion.rotations.shape == (60, 24, 4) and r.error.shape == (60, 4) and r.converged.shape == (60,)
    assert 0.9 < float(r.scale) < 1.2  # leg lengths: the humanoid's 0.94 m hip height against CMU's
    np.testing.assert_allclose(np.asarray(r.motion.root_positions), float(r.scale) * np.asarray(clip.root_positions),
                               rtol=1e-6)
    # the reported error is the distance from the scaled source effectors, measured here afresh
    src = np.asarray(anim.positions(clip))
    names = clip.skeleton.names
    want = float(r.scale) * (src[:, [names.index(n) for n in MAPPING.values()]] - src[:, :1]) + \
        np.asarray(r.motion.root_positions)[:, None]
    got = np.asarray(anim.positions(r.motion))[:, [H.index(n) for n in MAPPING]]
    np.testing.assert_allclose(np.linalg.norm(got - want, axis=-1), np.asarray(r.error), atol=2e-5)
    assert np.percentile(np.asarray(r.error), 95) < 0.01 and np.mean(np.asarray(r.converged)) > 0.5
    assert float(np.max(np.asarray(ik.limit_violation(H, r.motion.rotations)))) < 1e-6


@pytest.mark.slow
def test_gradients_through_a_retarget():
    """``check_grads`` in the source's bone offsets (which also set the default scale)
    and its rotations: a synthetic walk onto a rig 1.1x its size, LM for a fixed 8
    iterations a frame (``tol=0``: no frame stops, so the function is the one the
    derivative is taken of).  The central differences use ``eps = 1e-6``: at JAX's
    default 1e-4 their truncation error is 8e-4 against a derivative of 5.9 (it falls
    100x per 10x smaller step, to 8e-8 at 1e-6, measured on a 4-effector limited rig)."""
    m, _ = synthetic_walk(1.2, 1.0, 0.3, np.float64, T=4)
    names = ("pelvis", "l_hip", "l_knee", "l_ankle", "l_toe", "r_hip", "r_knee", "r_ankle", "r_toe")
    rig = ik.Skeleton(parents=m.skeleton.parents, offsets=1.1 * m.skeleton.offsets, names=names)
    mapping = {"l_ankle": "lankle", "r_ankle": "rankle"}

    def knees(offsets, rotations):
        sk = ik.Skeleton(parents=m.skeleton.parents, offsets=offsets, names=m.skeleton.names)
        clip = anim.Motion(skeleton=sk, rotations=rotations, root_positions=m.root_positions,
                           frame_time=m.frame_time)
        r = anim.retarget(clip, rig, mapping, max_iters=8, tol=0.0)
        return jnp.sum(anim.positions(r.motion)[:, [2, 6]] ** 2) + r.scale

    args = (m.skeleton.offsets, m.rotations)
    g = jax.grad(knees, argnums=(0, 1))(*args)
    assert all(np.all(np.isfinite(np.asarray(x))) and np.any(np.asarray(x) != 0) for x in g)
    check_grads(knees, args, order=1, modes=("rev",), eps=1e-6, atol=1e-6, rtol=1e-6)


def test_bad_mappings():
    w = anim.cmu_walk(np.float32)
    H = ik.humanoid(np.float32)
    for mapping, match in (({}, "non-empty"), ({"l_paw": "LeftWrist"}, "no joint named 'l_paw'"),
                           ({"l_hand": "LeftPaw"}, "no joint named 'LeftPaw'"), ({"pelvis": "Hips"}, "root")):
        with pytest.raises(ValueError, match=match):
            anim.retarget(w, H, mapping)
    with pytest.raises(TypeError, match="Skeleton"):
        anim.retarget(w, "humanoid", MAPPING)
    for bad in (-1.0, 0.0, np.nan, "big", (1.0, 2.0)):
        with pytest.raises(ValueError, match="scale"):
            anim.retarget(w, H, MAPPING, scale=bad)
