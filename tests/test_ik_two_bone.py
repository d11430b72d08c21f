"""``ik.two_bone``: the closed-form limb against its geometry, a numpy reference, jit, vmap,
gradients (NaN-free at the straight limb and on the root) and bad input."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxsim import ik


def reference(a, t, p, l1, l2, lo, hi):
    """The same limb by numpy, the middle joint by the two circles' intersection."""
    v = t - a
    dist = np.linalg.norm(v)
    span = [math.sqrt(l1 * l1 + l2 * l2 + 2 * l1 * l2 * math.cos(x)) for x in (hi, lo)]
    d = min(max(dist, span[0]), span[1])
    u = v / dist
    x = (l1 * l1 - l2 * l2 + d * d) / (2 * d)  # along u, from the root
    h = math.sqrt(max(l1 * l1 - x * x, 0.0))
    side = (p - a) - np.dot(p - a, u) * u
    n = side / np.linalg.norm(side)
    return a + x * u + h * n, a + d * u


def test_limbs_against_the_geometry_and_numpy():
    rng = np.random.default_rng(0)
    l1, l2, lo, hi = 0.3, 0.25, 0.1, 2.6
    a = rng.normal(size=(64, 3))
    t = a + rng.normal(size=(64, 3)) * 0.35  # some beyond reach, some too close
    p = a + rng.normal(size=(64, 3))
    r = ik.two_bone(a, t, p, (l1, l2), bend=(lo, hi))
    mid, end, bend = np.asarray(r.mid), np.asarray(r.end), np.asarray(r.bend)
    np.testing.assert_allclose(np.linalg.norm(mid - a, axis=-1), l1, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(end - mid, axis=-1), l2, atol=1e-12)
    assert np.all((bend >= lo - 1e-12) & (bend <= hi + 1e-12))
    cosb = np.sum((mid - a) * (end - mid), axis=-1) / (l1 * l2)
    np.testing.assert_allclose(np.cos(bend), cosb, atol=1e-12)
    ok = np.asarray(r.reached)
    assert 0 < ok.sum() < len(ok)  # the case has both
    np.testing.assert_allclose(end[ok], t[ok], atol=1e-12)
    dist = np.linalg.norm(t - a, axis=-1)
    span = [math.sqrt(l1 * l1 + l2 * l2 + 2 * l1 * l2 * math.cos(x)) for x in (hi, lo)]
    np.testing.assert_array_equal(ok, (dist >= span[0]) & (dist <= span[1]))
    for b in range(len(a)):
        m, e = reference(a[b], t[b], p[b], l1, l2, lo, hi)
        np.testing.assert_allclose(mid[b], m, atol=1e-10)
        np.testing.assert_allclose(end[b], e, atol=1e-12)
    # the middle joint lies on the pole's side of the root-target line, in their plane
    u = (end - a) / np.linalg.norm(end - a, axis=-1, keepdims=True)
    side = (p - a) - np.sum((p - a) * u, -1, keepdims=True) * u
    normal = np.cross(u, side)
    np.testing.assert_allclose(np.sum((mid - a) * normal, -1), 0.0, atol=1e-12)
    assert np.all(np.sum((mid - a) * side, -1) >= -1e-12)


def test_jit_vmap_float32_and_gradients():
    a, t, p = np.zeros(3), np.array([0.2, 0.3, 0.1]), np.array([0.0, 0.0, 1.0])
    f = lambda t: ik.two_bone(a, t, p, (0.3, 0.25), bend=(0.0, 2.5))  # noqa: E731
    eager = f(t)
    jitted = jax.jit(f)(t)
    np.testing.assert_allclose(jitted.mid, eager.mid, atol=1e-14)
    T = np.stack([t, t * 0.5, t * 3])
    batched = jax.vmap(f)(T)
    for k in range(3):
        np.testing.assert_allclose(batched.mid[k], f(T[k]).mid, atol=1e-14)
    r32 = ik.two_bone(a.astype(np.float32), t.astype(np.float32), p.astype(np.float32), (0.3, 0.25))
    assert r32.mid.dtype == jnp.float32
    check_grads(lambda t: f(t).mid, (t,), order=1, modes=("rev", "fwd"), atol=1e-6, rtol=1e-6)
    for tt in (np.array([2.0, 0.0, 0.0]), np.zeros(3), np.array([0.55, 0.0, 0.0])):  # beyond, on the root, straight
        g = jax.grad(lambda t: jnp.sum(f(t).mid) + jnp.sum(f(t).end) + f(t).bend)(tt)
        assert np.all(np.isfinite(np.asarray(g))), tt
        assert np.all(np.isfinite(np.asarray(f(tt).mid)))


def test_bad_input_raises():
    a = np.zeros(3)
    for lengths in ((0.3,), (0.3, 0.0), (-1.0, 0.2), (np.nan, 0.2)):
        with pytest.raises(ValueError, match="lengths"):
            ik.two_bone(a, a + 1, a + 2, lengths)
    for bend in ((1.0, 0.5), (-0.1, 1.0), (0.0, 4.0), 1.0):
        with pytest.raises(ValueError, match="bend"):
            ik.two_bone(a, a + 1, a + 2, (0.3, 0.2), bend=bend)
    with pytest.raises(ValueError, match="pole"):
        ik.two_bone(a, a + 1, np.array([np.nan, 0, 0]), (0.3, 0.2))
    with pytest.raises(ValueError, match="target"):
        ik.two_bone(a, np.zeros(2), a, (0.3, 0.2))
