"""Public functions that the fast tier's other tests do not reach, each checked against a
closed form or numpy on a tiny input (``test_api_coverage`` keeps the list honest)."""

from __future__ import annotations

import numpy as np
import pytest

from jaxsim import anim, cloth as C, curves, ik, viz

from _helpers import random_unit_quaternions


def _np_quat_mul(a, b):
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)


def test_global_rotations_compose_the_local_ones_down_the_tree():
    walk = anim.cmu_walk()
    clip = anim.Motion(skeleton=walk.skeleton, rotations=walk.rotations[:3], root_positions=walk.root_positions[:3],
                       translations=None if walk.translations is None else walk.translations[:3],
                       frame_time=walk.frame_time, channels=walk.channels, end_sites=walk.end_sites)
    G = np.asarray(anim.global_rotations(clip), np.float64)
    L = np.asarray(clip.rotations, np.float64)
    ref = np.empty_like(L)
    for j, p in enumerate(clip.skeleton.parents):
        ref[:, j] = L[:, j] if p < 0 else _np_quat_mul(ref[:, p], L[:, j])
    same_sign = np.sign(np.sum(G * ref, -1, keepdims=True))
    np.testing.assert_allclose(G, ref * same_sign, atol=1e-5)


def test_energy_is_springs_plus_gravity_and_kinetic_is_half_m_v2():
    c = C.lab_cloth(np.float64)
    rng = np.random.default_rng(0)
    x = np.asarray(c.rest) + 0.05 * rng.normal(size=c.rest.shape)
    v = rng.normal(size=x.shape)
    P = np.asarray(c.springs)
    length = np.linalg.norm(x[P[:, 1]] - x[P[:, 0]], axis=-1)
    springs = np.sum(0.5 * np.asarray(c.stiffness) * (length - np.asarray(c.rest_length)) ** 2)
    gravity = -np.sum(np.asarray(c.mass)[:, None] * np.asarray(c.gravity) * x)
    np.testing.assert_allclose(float(C.energy(c, x)), springs + gravity, rtol=1e-12)
    np.testing.assert_allclose(float(C.kinetic_energy(c, v)), 0.5 * np.sum(np.asarray(c.mass)[:, None] * v * v),
                               rtol=1e-12)


def test_energy_report_of_a_damped_rollout():
    c = C.lab_cloth(np.float64)
    s0 = C.State.at_rest(c)
    states, infos = C.rollout(c, s0, 1 / 60, 5)
    rep = C.energy_report(c, s0, states, infos)
    e = np.asarray(rep.energy)
    assert e.shape == (6,) and bool(rep.finite) and bool(rep.stable)
    ref = [float(C.energy(c, s0.x) + C.kinetic_energy(c, s0.v))]
    ref += [float(C.energy(c, x) + C.kinetic_energy(c, v)) for x, v in zip(states.x, states.v)]
    np.testing.assert_allclose(e, ref, rtol=1e-10)
    assert int(rep.rises) == int(np.sum(np.diff(ref) > 0))
    np.testing.assert_allclose(float(rep.net_change), ref[-1] - ref[0], rtol=1e-10)


def test_pin_mask():
    np.testing.assert_array_equal(C.pin_mask(5, [0, 3]), [True, False, False, True, False])


def test_cardioid_and_triangle_lie_in_the_plane_y0():
    h = curves.cardioid(40)
    t = np.linspace(0.0, 2 * np.pi, 40, endpoint=False)
    r = 0.5 * (1 - np.sin(t))
    np.testing.assert_allclose(h, np.stack([r * np.cos(t), np.zeros(40), r * np.sin(t)], -1), atol=1e-12)
    tri = curves.triangle(30, radius=0.4)
    assert tri.shape == (30, 3) and np.all(tri[:, 1] == 0)
    assert np.linalg.norm(tri[:, [0, 2]], axis=-1).max() <= 0.4 + 1e-12  # inscribed in the circle


def test_rotation_change_is_the_relative_angle():
    rng = np.random.default_rng(1)
    a = random_unit_quaternions(rng, (6,))
    ang = rng.uniform(0, np.pi, 6)
    axis = rng.normal(size=(6, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    turn = np.concatenate([np.cos(ang / 2)[:, None], np.sin(ang / 2)[:, None] * axis], -1)
    np.testing.assert_allclose(np.asarray(ik.rotation_change(a, _np_quat_mul(a, turn))), ang, atol=1e-5)


def test_new_figure_is_a_figure_with_axes():
    fig, ax = viz.new_figure(3.0, 2.0, dpi=50)
    assert fig.get_size_inches().tolist() == [3.0, 2.0] and ax in fig.axes


def test_energy_report_refuses_states_of_another_scene():
    c, other = C.lab_cloth(np.float64), C.grid(3, 0.1, dtype=np.float64)
    s0 = C.State.at_rest(c)
    states, infos = C.rollout(c, s0, 1 / 60, 2)
    _, other_infos = C.rollout(other, C.State.at_rest(other), 1 / 60, 3)
    with pytest.raises(ValueError, match=r"state0.x must be \(121, 3\) .* got \(16, 3\)"):
        C.energy_report(c, C.State.at_rest(other), states, infos)
    with pytest.raises(ValueError, match=r"states.x must be \(T, 16, 3\) .* got \(2, 121, 3\)"):
        C.energy_report(other, C.State.at_rest(other), states, infos)
    with pytest.raises(ValueError, match="infos must hold the rollout's 2 steps"):
        C.energy_report(c, s0, states, other_infos)


def test_self_contact_pairs_zero_is_refused_not_the_default():
    assert C.grid(3, 0.1, self_contact=True).self_contact_pairs == 8 * 16  # None: the default
    with pytest.raises(ValueError, match="self_contact_pairs must be an int >= 1, got 0"):
        C.grid(3, 0.1, self_contact=True, self_contact_pairs=0)
