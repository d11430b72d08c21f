"""``anim.retarget``: the CMU walk onto ``ik.humanoid()`` (its limits kept), effector errors
reported, and bad mappings raising."""

import numpy as np
import pytest

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


def test_bad_mappings():
    w = anim.cmu_walk(np.float32)
    H = ik.humanoid(np.float32)
    for mapping, match in (({}, "non-empty"), ({"l_paw": "LeftWrist"}, "no joint named 'l_paw'"),
                           ({"l_hand": "LeftPaw"}, "no joint named 'LeftPaw'"), ({"pelvis": "Hips"}, "root")):
        with pytest.raises(ValueError, match=match):
            anim.retarget(w, H, mapping)
    with pytest.raises(TypeError, match="Skeleton"):
        anim.retarget(w, "humanoid", MAPPING)
    with pytest.raises(ValueError, match="scale"):
        anim.retarget(w, H, MAPPING, scale=-1.0)
