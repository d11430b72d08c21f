"""``anim.lock_feet`` on the shipped CMU walk and on synthetic walks: no sliding in the
contact spans, bone lengths kept, frames away from the spans unchanged, and gradients
through it."""

import dataclasses

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


def _static(bend_deg, T=60):
    """A synthetic biped standing still, both knees bent by ``bend_deg`` (0: straight legs)."""
    m, _ = synthetic_walk(1.0, 1.0, 0.0, np.float64, T=T)
    rot = np.tile(np.asarray(m.rotations)[:1], (T, 1, 1))
    a = np.radians(bend_deg)
    for j in (1, 3, 5, 7):  # hips and ankles straight
        rot[:, j] = (1.0, 0.0, 0.0, 0.0)
    rot[:, 2] = rot[:, 6] = (np.cos(a / 2), np.sin(a / 2), 0.0, 0.0)
    return dataclasses.replace(m, rotations=rot, root_positions=np.tile(np.asarray(m.root_positions)[:1], (T, 1)))


def test_a_straight_leg_bends_in_its_own_plane():
    """A static clip on straight legs: the knee stays in the leg's plane (x = const) and
    bends forward, toward the toe (it moved 8.9 mm sideways and backward); with the knee bent
    20 degrees the clip is unchanged."""
    down = np.zeros((60, 2), bool)
    down[10:50] = True
    st = _static(0.0)
    out, info = anim.lock_feet(st, ("ltoe", "rtoe"), down, info=True)
    P0, P1 = np.asarray(anim.positions(st)), np.asarray(anim.positions(out))
    for knee in (2, 6):
        assert np.abs(P1[:, knee, 0] - P0[:, knee, 0]).max() < 1e-9  # in the leg's plane
        assert np.all(P1[:, knee, 2] - P0[:, knee, 2] >= -1e-12)  # forward, not backward
    assert bool(np.all(info.held))
    bent = _static(20.0)
    np.testing.assert_allclose(np.asarray(anim.positions(anim.lock_feet(bent, ("ltoe", "rtoe"), down))),
                               np.asarray(anim.positions(bent)), atol=1e-9)


def test_a_lock_beyond_the_legs_reach_is_reported():
    """The root moves 3 m during one contact with a 0.93 m leg: the foot cannot stay; the
    frames that miss are flagged with the largest miss, and the plain call warns."""
    down = np.zeros((60, 2), bool)
    down[5:55] = True
    st = _static(20.0)
    root = np.asarray(st.root_positions).copy()
    root[:, 2] = np.linspace(0.0, 3.0, 60)
    mv = dataclasses.replace(st, root_positions=root)
    out, info = anim.lock_feet(mv, ("ltoe", "rtoe"), down, info=True)
    held = np.asarray(info.held)
    assert held[:, 0].any() and not held[:, 0].all()  # the middle of the span holds, its ends cannot
    P = np.asarray(anim.positions(out))[:, 4]
    lock = np.asarray(anim.positions(mv))[5:55, 4].mean(0)
    np.testing.assert_allclose(np.asarray(info.miss)[5:55, 0], np.linalg.norm(P[5:55] - lock, axis=-1), atol=1e-9)
    assert float(info.max_miss[0]) > 0.2
    with pytest.warns(UserWarning, match=r"could not hold foot joint 4 .* missed by up to 0\.\d"):
        anim.lock_feet(mv, ("ltoe", "rtoe"), down)
