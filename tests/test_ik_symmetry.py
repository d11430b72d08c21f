"""The start's bend of straight branches on their targets' lines (``_symmetry.bend_straight``,
FABRIK paper §5.4) against a NumPy port of its sequential rule, and FK by a rolled loop over
tree levels against the unrolled levels."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import ik
from jaxsim.ik._model.skeleton import topology
from jaxsim.ik._model.stacked import fk_stacked
from jaxsim.ik._solvers.symmetry import SYMMETRY_BREAK_ANGLE, bend_straight, branch_segments

from _helpers import fk_reference, quat_matrix, random_unit_quaternions


def _qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _perpendicular(a):  # the rule of ``_geometry.quat.perpendicular``
    ax, ay, az = np.abs(a)
    p = np.array([0.0, a[2], -a[1]]) if ax <= 0.57 * (ax + ay + az) else np.array([-a[2], 0.0, a[0]])
    return p / np.linalg.norm(p)


def bend_reference(topo, L, P, G, targets, tol):
    """One pose, branch by branch and joint by joint from the top: the first joint ``seg[i]``
    whose bones down to the effector are parallel and point at the (unreached) target has the
    joint below it turned by ``SYMMETRY_BREAK_ANGLE`` about a perpendicular of its bone."""
    L = np.array(L, float)

    def parallel(u, v):
        return np.linalg.norm(np.cross(u, v)) <= 1e-6 * np.linalg.norm(u) * np.linalg.norm(v)

    for k, seg in enumerate(branch_segments(topo)):
        if len(seg) < 2:
            continue
        bones = [P[seg[j + 1]] - P[seg[j]] for j in range(len(seg) - 1)]
        taken = np.linalg.norm(P[seg[-1]] - targets[k]) <= tol
        for i in range(max(len(seg) - 2, 1)):
            straight = all(parallel(bones[j], bones[j + 1]) for j in range(i, len(bones) - 1))
            if taken or not (straight and parallel(bones[i], targets[k] - P[seg[i]])):
                continue
            taken = True
            m = seg[i + 1] if len(seg) - i > 2 else seg[i]
            h = 0.5 * SYMMETRY_BREAK_ANGLE
            r = np.concatenate([[np.cos(h)], np.sin(h) * _perpendicular(bones[i])])
            gp = G[topo.parents[m]] if m > 0 else np.array([1.0, 0, 0, 0])
            L[m] = _qmul(gp * [1, -1, -1, -1], _qmul(r, _qmul(gp, L[m])))
    return L


def _fork():
    """A sub-base with two one-bone branches: both bends land on the sub-base."""
    return ik.Skeleton(parents=(-1, 0, 1, 1), offsets=np.array([[0, 0, 0], [0, 1.0, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]]))


def _branchy():
    """Root, a sub-base with a one-bone and a straight two-bone branch."""
    offsets = np.array([[0, 0, 0], [0, 1.0, 0], [0.6, 0.3, 0.1], [-0.5, 0.3, 0.0], [-0.25, 0.15, 0.0]])
    return ik.Skeleton(parents=(-1, 0, 1, 1, 3), offsets=offsets)


@pytest.mark.parametrize("case", ["humanoid", "branchy", "fork", "fork_root_effector"])
def test_bend_straight_matches_the_sequential_rule(case):
    if case == "humanoid":
        sk = ik.humanoid(limits=False)
        eff = tuple(sk.index(n) for n in ik.HUMANOID_EFFECTORS)
    else:
        sk = _branchy() if case == "branchy" else _fork()
        eff = {"branchy": (2, 4), "fork": (2, 3), "fork_root_effector": (0, 2, 3)}[case]
    topo = topology(tuple(sk.parents), eff)
    rng = np.random.default_rng(3)
    n, J = 24, sk.num_joints
    rest = np.tile([1.0, 0, 0, 0], (J, 1))
    L = np.where(rng.uniform(size=(n, 1, 1)) < 0.6, rest, random_unit_quaternions(rng, (n, J)))
    P0 = np.asarray(ik.fk(sk).positions)
    segs = branch_segments(topo)
    T = np.empty((n, len(eff), 3))
    for b in range(n):
        for k, seg in enumerate(segs):
            top = seg[int(rng.integers(0, max(len(seg) - 1, 1)))]  # the line from some joint of the branch
            T[b, k] = P0[top] + rng.uniform(0.3, 1.6) * (P0[seg[-1]] - P0[top])
    T[::5] = P0[list(eff)]  # reached: no bend
    T[2::7] += rng.normal(size=T[2::7].shape)  # off the line: no bend
    Lj = jnp.asarray(L)
    P, G = fk_stacked(topo.parents, sk.offsets, Lj)
    got = np.asarray(jax.jit(functools.partial(bend_straight, topo))(Lj, P, G, jnp.asarray(T), 1e-4))
    P, G = np.asarray(P), np.asarray(G)
    want = np.stack([bend_reference(topo, L[b], P[b], G[b], T[b], 1e-4) for b in range(n)])
    np.testing.assert_allclose(got, want, atol=1e-14)
    bent = np.any(np.abs(got - L) > 0, axis=(-2, -1))
    assert 0 < bent.sum() < n  # the cases include bends and none
    if case == "fork":
        assert np.any(np.sum(np.abs(got - L) > 0, axis=-1)[:, 1] > 0)  # the sub-base, turned for both branches


def test_fk_by_levels_rolled_and_unrolled_match_numpy():
    rng = np.random.default_rng(0)
    H = ik.humanoid(limits=False)
    R = jnp.asarray(random_unit_quaternions(rng, (3, H.num_joints)))

    def loss(L, unroll):
        P, G = fk_stacked(H.parents, H.offsets, L, unroll=unroll)
        return jnp.sum(jnp.sin(P)) + jnp.sum(G[..., 1:] ** 3), (P, G)

    grads = {}
    for unroll in (True, False):
        (_, (P, G)), grads[unroll] = jax.jit(jax.value_and_grad(loss, has_aux=True), static_argnums=1)(R, unroll)
        for b in range(3):
            Pw, Gw = fk_reference(H.parents, np.asarray(H.offsets), np.asarray(R[b]), frames=True)
            np.testing.assert_allclose(P[b], Pw, atol=1e-12)
            np.testing.assert_allclose(np.stack([quat_matrix(g) for g in np.asarray(G[b])]), Gw, atol=1e-12)
    np.testing.assert_allclose(grads[False], grads[True], atol=1e-12)
    assert bool(jnp.all(jnp.isfinite(grads[False])))
