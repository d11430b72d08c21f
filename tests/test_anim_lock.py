"""``anim.lock_feet`` on the shipped CMU walk and on synthetic walks: no sliding in the
contact spans, bone lengths kept, frames away from the spans unchanged, and gradients
through it."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from _helpers import synthetic_walk
from jaxsim import anim

FEET = ("LeftToe", "RightToe")


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_synthetic_walks_stop_sliding(dtype):
    rng = np.random.default_rng(3)
    feet, bar = ("ltoe", "rtoe"), (1e-9 if dtype == np.float64 else 1e-3)  # the bar: 1 mm
    for _ in range(3):  # gaits of one shape: one compiled program
        m, stance = synthetic_walk(rng.uniform(0.8, 1.6), rng.uniform(0.8, 1.2), rng.uniform(0, 2 * np.pi), dtype)
        for down in (stance, anim.foot_contacts(m, feet)):
            assert down.any(0).all() and not down.all()
            assert np.all(anim.foot_slide(m, feet, down) > 0.005)
            locked = anim.lock_feet(m, feet, down)
            assert locked.rotations.dtype == dtype
            assert np.all(anim.foot_slide(locked, feet, down) <= bar)
            P0, P1 = np.asarray(anim.positions(m), np.float64), np.asarray(anim.positions(locked), np.float64)
            par = list(m.skeleton.parents[1:])
            np.testing.assert_allclose(np.linalg.norm(P1[:, 1:] - P1[:, par], axis=-1),
                                       np.linalg.norm(P0[:, 1:] - P0[:, par], axis=-1), atol=10 * bar)
            away = ~np.convolve(down.any(1), np.ones(2 * 6 + 1), "same").astype(bool)
            assert np.abs(P1 - P0)[away].max(initial=0.0) <= 10 * bar
            assert np.abs(P1 - P0).max() < 0.15  # close to the input (a toe moves by its slide at most)


def test_array_likes_become_the_skeletons_dtype():
    m, _ = synthetic_walk(1.0, 1.0, 0.0, np.float32, T=4)
    assert isinstance(m.rotations, jax.Array) and m.rotations.dtype == np.float32
    assert m.root_positions.dtype == np.float32
    bad = np.asarray(m.rotations).copy()
    bad[2, 3, 1] = np.nan
    with pytest.raises(ValueError, match=r"rotations must be finite; not in frames \[2\]"):
        anim.Motion(skeleton=m.skeleton, rotations=bad, root_positions=m.root_positions)
    with pytest.raises(ValueError, match="root_positions must hold real numbers"):
        anim.Motion(skeleton=m.skeleton, rotations=m.rotations, root_positions=np.full((4, 3), "x"))


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
