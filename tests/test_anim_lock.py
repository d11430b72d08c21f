"""``anim.lock_feet`` on the shipped CMU walk: no sliding in the contact spans, bone lengths
kept, frames away from the spans unchanged, and gradients through it."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxsim import anim

FEET = ("LeftToe", "RightToe")


@pytest.fixture(scope="module")
def walk():
    w = anim.cmu_walk(np.float64)
    return w, anim.foot_contacts(w, FEET)


def test_feet_stay_put_in_their_spans(walk):
    w, down = walk
    before = anim.foot_slide(w, FEET, down)
    assert np.all(before > 0.02)  # the clip's toes slide by centimetres
    locked = anim.lock_feet(w, FEET, down)
    assert np.all(anim.foot_slide(locked, FEET, down) <= 1e-6)  # and not at all after (the bar: 1 mm)
    P0, P1 = np.asarray(anim.positions(w)), np.asarray(anim.positions(locked))
    par = list(w.skeleton.parents[1:])
    np.testing.assert_allclose(np.linalg.norm(P1[:, 1:] - P1[:, par], axis=-1),
                               np.linalg.norm(P0[:, 1:] - P0[:, par], axis=-1), atol=1e-12)  # bone lengths kept
    away = ~np.convolve(down.any(1), np.ones(2 * 6 + 1), "same").astype(bool)  # beyond the 6-frame blends
    assert away.sum() > 0 and np.abs(P1 - P0)[away].max() < 1e-12
    drop = np.asarray(w.root_positions - locked.root_positions)
    assert np.all(drop[:, [0, 2]] == 0) and 0 <= drop[:, 1].min() and drop[:, 1].max() < 0.03  # lowered a little
    inside = down.any(1)
    assert np.abs(P1 - P0)[inside].max() < 0.1  # close to the input in the spans too


@pytest.mark.slow
def test_gradients_through_the_lock(walk):
    w, down = walk
    short = anim.Motion(skeleton=w.skeleton, rotations=w.rotations[:40], root_positions=w.root_positions[:40],
                        frame_time=w.frame_time, channels=w.channels)
    c = down[:40]
    assert c.any() and not c.all()

    def toe_path(offsets):
        sk = w.skeleton.__class__(parents=w.skeleton.parents, offsets=offsets, names=w.skeleton.names)
        m = anim.Motion(skeleton=sk, rotations=short.rotations, root_positions=short.root_positions,
                        frame_time=w.frame_time, channels=w.channels)
        return jnp.sum(anim.positions(anim.lock_feet(m, FEET, c))[:, [5, 10]] ** 2)

    g = jax.grad(toe_path)(w.skeleton.offsets)
    assert np.all(np.isfinite(np.asarray(g)))
    check_grads(toe_path, (w.skeleton.offsets,), order=1, modes=("rev",), atol=1e-5, rtol=1e-5)


def test_bad_arguments(walk):
    w, down = walk
    with pytest.raises(ValueError, match="three joints above"):
        anim.lock_feet(w, ("LHipJoint",), down[:, :1])
    with pytest.raises(ValueError, match="zero-length bones"):
        anim.lock_feet(w, ("lhand",), down[:, :1])
    with pytest.raises(ValueError, match="blend"):
        anim.lock_feet(w, FEET, down, blend=-1)
    with pytest.raises(ValueError, match="contacts must have shape"):
        anim.lock_feet(w, FEET, down[:10])
