"""``anim.foot_contacts`` and ``anim.foot_slide`` on synthetic walks with known stance
frames and drift, and on the shipped CMU clip."""

import numpy as np
import pytest

from jaxsim import anim, ik

FPS = 120.0


def walk_of(foot_path):
    """A 2-joint clip whose second joint follows ``foot_path (T, 3)`` (the root carries it)."""
    T = len(foot_path)
    sk = ik.Skeleton(parents=(-1, 0), offsets=np.array([[0.0, 0.9, 0.0], [0.0, -0.9, 0.0]]), names=("hips", "foot"))
    rot = np.zeros((T, 2, 4))
    rot[..., 0] = 1.0
    return anim.Motion(skeleton=sk, rotations=rot, root_positions=foot_path + [0.0, 0.9, 0.0], frame_time=1 / FPS,
                       channels=(("Xposition", "Yposition", "Zposition"), ()))


def synthetic(drift=0.004, noise=0.002, seed=0):
    """Three stances of 60 frames (drifting ``drift`` m along x, heights with ``noise``)
    and two swings of 40 frames (a 0.1 m arc at 1 m/s); returns the path and the stance mask."""
    rng = np.random.default_rng(seed)
    path, stance, x = [], [], 0.0
    for k in range(5):
        if k % 2 == 0:
            n = 60
            xs = x + np.linspace(0.0, drift, n)
            ys = noise * rng.uniform(0, 1, n)
            stance += [True] * n
        else:
            n = 40
            s = np.linspace(0, 1, n + 2)[1:-1]
            xs = x + drift + 0.4 * s
            ys = 0.1 * np.sin(np.pi * s)
            stance += [False] * n
        path.append(np.stack([xs, ys, np.zeros(n)], 1))
        x = xs[-1]
    return np.concatenate(path), np.array(stance)


def test_stances_found_and_slide_measured():
    path, stance = synthetic()
    m = walk_of(path)
    down = anim.foot_contacts(m, "foot", floor=0.0)
    assert down.shape == (len(path), 1)
    spans = anim.contact_spans(down[:, 0])
    assert len(spans) == 3  # one span per stance, none in a swing
    truth = anim.contact_spans(stance)
    for (a, b), (ta, tb) in zip(spans, truth):
        assert abs(a - ta) <= 3 and abs(b - tb) <= 3  # the edges, where the swing is still slow and low
    interior = np.concatenate([np.arange(ta + 3, tb - 3) for ta, tb in truth])
    assert down[interior, 0].all()
    slide = anim.foot_slide(m, "foot", down)
    assert slide.shape == (1,) and 0.0035 <= slide[0] <= 0.0045  # the 4 mm drift


def test_hysteresis_does_not_flicker():
    path, _ = synthetic(noise=0.0)
    path[:60, 1] = 0.05 - 0.008 * np.cos(2 * np.pi * np.arange(60) / 40)  # hovering about the 0.05 m threshold
    m = walk_of(path)
    down = anim.foot_contacts(m, "foot", floor=0.0, min_frames=1)
    assert down[:58, 0].all()  # down from frame 0 (to the jump into the swing), within release * height
    strict = anim.foot_contacts(m, "foot", floor=0.0, release=1.0, min_frames=1)
    assert len(anim.contact_spans(strict[:60, 0])) >= 2 and not strict[:60, 0].all()  # without it: flicker


def test_the_cmu_walk():
    w = anim.cmu_walk()
    feet = ("LeftToe", "RightToe")
    down = anim.foot_contacts(w, feet)
    assert 0.4 < down.mean() < 0.7  # each foot is down about half the time in a walk
    spans = anim.contact_spans(down[:, 1])
    assert len(spans) >= 6 and all(b - a >= 3 for a, b in spans)
    slide = anim.foot_slide(w, feet, down)
    assert np.all((slide > 0.005) & (slide < 0.06))  # real mocap slides by millimetres to centimetres


def test_bad_arguments():
    m = walk_of(synthetic()[0])
    for kw, match in ((dict(feet="toe"), "no joint named 'toe'"), (dict(feet=(5,)), "feet must be joint names"),
                      (dict(feet=()), "at least one"), (dict(feet="foot", height=-1.0), "height"),
                      (dict(feet="foot", speed=np.nan), "speed"), (dict(feet="foot", release=0.5), "release"),
                      (dict(feet="foot", min_frames=0), "min_frames"), (dict(feet="foot", up=3), "up")):
        with pytest.raises(ValueError, match=match):
            anim.foot_contacts(m, **kw)
    with pytest.raises(ValueError, match="contacts must have shape"):
        anim.foot_slide(m, "foot", np.zeros((3, 1), bool))


def test_values_that_would_be_reinterpreted_are_refused():
    """``floor`` must be a finite number (nan and -inf found no contacts, "x" raised from
    float()), ``release`` finite, bools are not joint ids or frame counts, and a contact
    flag of 0.3 is not True."""
    m = walk_of(synthetic()[0])
    for kw, match in ((dict(floor="x"), "floor must be a real number, got 'x'"),
                      (dict(floor=np.nan), "floor must be finite"), (dict(floor=-np.inf), "floor must be finite"),
                      (dict(release=np.inf), "release must be finite"),
                      (dict(min_frames=True), "min_frames must be an int, got True"), (dict(up=True), "up must be")):
        with pytest.raises(ValueError, match=match):
            anim.foot_contacts(m, "foot", **kw)
    with pytest.raises(ValueError, match="feet must be joint names or indices"):
        anim.foot_contacts(m, feet=True)
    down = anim.foot_contacts(m, "foot", floor=0.0)
    assert down.any() and np.array_equal(anim.foot_slide(m, "foot", down.astype(int)), anim.foot_slide(m, "foot", down))
    with pytest.raises(ValueError, match=r"contacts must be bools \(or 0 and 1\), got np.float64\(0.3\)"):
        anim.foot_slide(m, "foot", np.where(down, 0.3, 0.0))
