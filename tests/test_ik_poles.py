"""Pole targets (``solve(..., poles={joint: point})``): LM bends each limb's middle joint
toward its pole, checked against ``two_bone``'s closed form and an independent numpy
half-plane test; implicit derivatives with respect to the pole; and every bad input."""

import dataclasses

import jax
import numpy as np
import pytest

from jaxsim import ik

MET = ik.LevenbergMarquardt(100, 1e-11)


def arm():
    """A shoulder (ball, the root), an elbow (ball) and a hand: a free two-bone limb."""
    return ik.Chain(np.array([[0.0, 0, 0], [0, -1.0, 0], [0, -0.8, 0]]))


def side(a, m, e, p):
    """``(distance of m from the half-plane of the line a-e and p, cos of the angle between
    the bend and the pole around the line)``, in numpy."""
    u = (e - a) / np.linalg.norm(e - a)
    mp = (m - a) - np.dot(m - a, u) * u
    pp = (p - a) - np.dot(p - a, u) * u
    cos = np.dot(mp, pp) / max(np.linalg.norm(mp) * np.linalg.norm(pp), 1e-300)
    return np.linalg.norm(mp - np.linalg.norm(mp) * pp / np.linalg.norm(pp)), cos


@pytest.mark.parametrize("pole", [(0.0, -0.5, 1.0), (0.0, -0.5, -1.0), (1.0, 0.2, 0.3)])
def test_the_elbow_goes_where_two_bone_puts_it(pole):
    """A free limb with a reachable target and a pole: LM's elbow is two_bone's, on the pole's side."""
    chain, t, pole = arm(), np.array([0.6, -1.1, 0.2]), np.asarray(pole)
    r = ik.solve(chain, t, solver=MET, poles={1: pole})
    assert bool(r.converged)
    ref = ik.two_bone(np.zeros(3), t, pole, (1.0, 0.8))
    np.testing.assert_allclose(r.positions[1], ref.mid, atol=1e-8)
    dist, cos = side(*(np.asarray(r.positions[i]) for i in range(3)), pole)
    assert dist < 1e-9 and cos > 1 - 1e-9


def test_implicit_derivatives_with_respect_to_the_pole_and_target_equal_two_bones():
    chain, t0, p0 = arm(), np.array([0.6, -1.1, 0.2]), np.array([0.0, -0.5, 1.0])

    def elbow(t, p):
        return ik.solve(chain, t, solver=dataclasses.replace(MET, implicit_diff=True), poles={1: p}).positions[1]

    got = jax.jit(jax.jacfwd(elbow, argnums=(0, 1)))(t0, p0)
    want = jax.jacfwd(lambda t, p: ik.two_bone(np.zeros(3), t, p, (1.0, 0.8)).mid, argnums=(0, 1))(t0, p0)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, atol=1e-7)
    assert np.abs(np.asarray(got[1])).max() > 0.1  # the pole moves the elbow


@pytest.mark.slow
def test_humanoid_poles_put_every_converged_limb_on_its_pole_side():
    """Elbow poles behind the shoulders and knee poles in front of the hips, 32 reachable sets
    of the limited humanoid: every converged set has each limb on its pole's side (numpy),
    and without the poles some would not be (the test can fail)."""
    H = ik.humanoid(np.float64)
    eff = tuple(H.index(n) for n in ik.HUMANOID_EFFECTORS)
    rng = np.random.default_rng(3)
    ax = rng.normal(size=(32, H.num_joints, 3))
    ax /= np.linalg.norm(ax, axis=-1, keepdims=True)
    ang = rng.uniform(0, 1.0, size=(32, H.num_joints, 1))
    q = np.asarray(ik.project_limits(H, np.concatenate([np.cos(ang / 2), np.sin(ang / 2) * ax], -1)))
    P = np.asarray(ik.fk(H, q).positions)
    limbs = {"l_elbow": ("l_shoulder", "l_hand", (0, -0.3, -0.5)), "r_elbow": ("r_shoulder", "r_hand", (0, -0.3, -0.5)),
             "l_knee": ("l_hip", "l_ankle", (0, -0.3, 0.6)), "r_knee": ("r_hip", "r_ankle", (0, -0.3, 0.6))}
    poles = {m: P[:, H.index(a)] + np.asarray(off) for m, (a, _, off) in limbs.items()}
    solve = jax.jit(lambda T, poles: ik.solve(H, T, effectors=eff, poles=poles))
    res = solve(P[:, eff], poles)
    conv = np.asarray(res.converged)
    assert conv.mean() > 0.75
    Pr = np.asarray(res.positions)

    def worst(Pr, sets):
        return max(side(Pr[s, H.index(a)], Pr[s, H.index(m)], Pr[s, H.index(e)], poles[m][s])[0]
                   for m, (a, e, _) in limbs.items() for s in sets)

    assert worst(Pr, np.flatnonzero(conv)) <= 1e-4
    free = np.asarray(ik.solve(H, P[:, eff], effectors=eff).positions)
    assert worst(free, range(32)) > 0.05


def test_bad_poles_raise():
    H = ik.humanoid(np.float64)
    eff = tuple(H.index(n) for n in ik.HUMANOID_EFFECTORS)
    T = np.asarray(ik.fk(H).positions)[list(eff)]
    ok = np.array([0.0, 1.0, -1.0])
    cases = [
        ({"pelvis": ok}, "root is no limb"),
        ({"spine1": ok}, "effectors .* are below it"),
        ({"l_hand": ok}, "0 of the effectors"),
        ({"l_shoulder": ok}, "is 3 joints below it"),
        ({"nose": ok}, "pole joint 'nose'"),
        ({99: ok}, "pole joint 99"),
        ({"l_elbow": np.array([np.nan, 0.0, 0.0])}, "pole on joint 'l_elbow'"),
        ({"l_elbow": np.zeros(2)}, "shape"),
        ({"l_elbow": np.zeros((3, 3))}, "batch shape"),
        ({"l_elbow": np.asarray(ik.fk(H).positions)[H.index("l_shoulder")]}, "on the limb's root"),
        ([ok], "must be a dict"),
    ]
    for poles, msg in cases:
        with pytest.raises(ValueError, match=msg):
            ik.solve(H, T, effectors=eff, poles=poles)
    with pytest.raises(ValueError, match="poles need solver='lm'"):
        ik.solve(H, T, effectors=eff, solver="fabrik", poles={"l_elbow": ok})
