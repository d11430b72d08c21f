"""Cloth self-contact: distances, broadphase, additive CCD, the barrier, and scenes that
must never pass through themselves (checked by an independent triangle-triangle test)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.optimize import minimize

from jaxsim import cloth as C
from jaxsim.cloth._self import broadphase as bp, ccd, pairs as sp, terms as sct
from jaxsim.cloth._self.distance import columns, pair_distance2, point_triangle2, point_triangle2_soa, \
    segment_segment2, segment_segment2_soa
from jaxsim.cloth._self.terms import _pair_energy, build
from jaxsim.cloth._implicit.contact import _d, barrier

from _helpers import all_eqns, self_intersections, step_jaxpr, triangle_pairs_intersect


def _ref_point_triangle2(p, a, b, c):
    """min over the triangle of |p - q|^2 by SLSQP on barycentric coordinates (float64)."""
    f = lambda uv: np.sum((a + uv[0] * (b - a) + uv[1] * (c - a) - p) ** 2)  # noqa: E731
    best = np.inf
    for s in ((1 / 3, 1 / 3), (0.8, 0.1), (0.1, 0.8), (0.05, 0.05)):
        r = minimize(f, s, method="SLSQP", bounds=[(0, 1), (0, 1)], tol=1e-14,
                     constraints=[{"type": "ineq", "fun": lambda uv: 1 - uv[0] - uv[1]}])
        best = min(best, r.fun)
    return best


def _ref_segment2(a0, a1, b0, b1):
    f = lambda st_: np.sum((a0 + st_[0] * (a1 - a0) - b0 - st_[1] * (b1 - b0)) ** 2)  # noqa: E731
    return min(minimize(f, s, method="L-BFGS-B", bounds=[(0, 1), (0, 1)], tol=1e-15).fun
               for s in ((0.5, 0.5), (0, 0), (1, 1), (0, 1), (1, 0)))


def test_distances_against_numpy_references():
    rng = np.random.default_rng(0)
    pt = jax.jit(point_triangle2)
    ee = jax.jit(segment_segment2)
    for _ in range(30):
        P = rng.normal(size=(4, 3))
        assert float(pt(*P)) == pytest.approx(_ref_point_triangle2(*P), rel=1e-6, abs=1e-12)
        assert float(ee(*P)) == pytest.approx(_ref_segment2(*P), rel=1e-6, abs=1e-12)
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])
    # degenerate configurations: a point on an edge, on a vertex, above the interior
    assert float(pt(np.array([0.5, 0, 0]), a, b, c)) == 0.0
    assert float(pt(np.array([1.0, 0, 0]), a, b, c)) == 0.0
    assert float(pt(np.array([0.2, 0.2, 0.3]), a, b, c)) == pytest.approx(0.09, rel=1e-14)
    # parallel edges, overlapping and apart; collinear; crossing
    assert float(ee(a, b, np.array([0.5, 0.1, 0]), np.array([2.0, 0.1, 0]))) == pytest.approx(0.01, rel=1e-14)
    assert float(ee(a, b, np.array([1.5, 0.1, 0]), np.array([2.0, 0.1, 0]))) == pytest.approx(0.26, rel=1e-14)
    assert float(ee(a, b, np.array([2.0, 0, 0]), np.array([3.0, 0, 0]))) == pytest.approx(1.0, rel=1e-14)
    assert float(ee(a, b, np.array([0.5, -1, 0.2]), np.array([0.5, 1, 0.2]))) == pytest.approx(0.04, rel=1e-14)


def test_pair_distance_derivatives_equal_autodiff_of_the_pieces():
    """``pair_distance2``'s rule (the nearest points held) gives the same first and second
    derivatives as autodiff through the pieces' ``where`` and ``minimum``, in every piece
    (interior, edges, vertices; lines and ends), on random pairs and on degenerate ones
    (float64).  Where two pieces tie there is no Hessian, so no pair here ties.  It fails if a piece's factors are wrong."""
    rng = np.random.default_rng(3)
    X = rng.normal(size=(64, 4, 3))
    X[:16, 0] *= 0.2  # points near the triangles: the interior piece
    X[16:24, 3] = X[16:24, 2] + 1e-9 * rng.normal(size=(8, 3))  # nearly point-sized edges
    X[24:32, 1] = X[24:32, 0] + (X[24:32, 3] - X[24:32, 2])  # parallel edges, apart along their direction
    X[24:32, 2:] += 3.0 * (X[24:32, 1] - X[24:32, 0])[:, None]  # (overlapping ones tie: no Hessian)
    X = jnp.asarray(X)
    plain = {0: point_triangle2_soa, 1: segment_segment2_soa}
    for kind in (0, 1):
        def f(X, kind=kind):
            return jnp.sum(jnp.sqrt(pair_distance2(kind, X)) * jnp.arange(1.0, 65.0))

        def g(X, kind=kind):
            return jnp.sum(jnp.sqrt(plain[kind](*columns(X))) * jnp.arange(1.0, 65.0))

        assert float(f(X)) == float(g(X))
        np.testing.assert_allclose(jax.jit(jax.grad(f))(X), jax.jit(jax.grad(g))(X), rtol=1e-9, atol=1e-12)
        Hf = jax.jit(jax.hessian(f))(X).reshape(64 * 12, 64 * 12)
        Hg = jax.jit(jax.hessian(g))(X).reshape(64 * 12, 64 * 12)
        np.testing.assert_allclose(Hf, Hg, rtol=1e-8, atol=1e-9 * float(np.max(np.abs(Hg))))


def test_barrier_derivatives_finite_down_to_contact():
    """The pair energies, gradients and Hessians have no NaN as d -> 0 and beyond dhat,
    for point-triangle and for (near-)parallel edges (the mollifier)."""
    c = C.grid(2, 0.5, self_contact=True)
    sc = build(c, 10.0)
    ids = jnp.array([0, 1, 2, 3], jnp.int32)
    for kind in (0, 1):
        e_of = lambda X, i, kind=kind: _pair_energy(sc, kind, X[None], i[None])[0]  # noqa: E731
        f = jax.jit(lambda X, i, e_of=e_of: (e_of(X, i), jax.grad(e_of)(X, i), jax.hessian(e_of)(X, i)))
        for d in (1e-12, 1e-8, 1e-5, 0.5 * float(sc.dhat), 2 * float(sc.dhat)):
            for tilt in (0.0, 1e-9, 0.3):
                X = jnp.array([[0.2, d, 0.2], [0, 0, 0], [1.0, 0, tilt], [0, 0, 1.0]])
                if kind == 1:
                    X = jnp.array([[0, d, 0], [1.0, d, tilt], [0.0, 0, 0], [1.0, 0, 0]])
                e, g, H = f(X, ids)
                assert np.isfinite(float(e)) and np.all(np.isfinite(g)) and np.all(np.isfinite(H)), (kind, d, tilt)
                assert (float(e) > 0) == (d < float(sc.dhat) and (kind == 0 or tilt > 0)), (kind, d, tilt)


def _boxes(rng, n, size):
    c = rng.uniform(0, 1, (n, 3))
    r = rng.uniform(0, size, (n, 3))
    return jnp.asarray(c - r), jnp.asarray(c + r)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), size=st.floats(0.001, 0.1))
def test_broadphase_equals_brute_force(seed, size):
    rng = np.random.default_rng(seed)
    lo_a, hi_a = _boxes(rng, 120, size)
    lo_b, hi_b = _boxes(rng, 90, size)
    ref = np.all((np.asarray(lo_a)[:, None] <= np.asarray(hi_b)[None]) & (np.asarray(lo_b)[None] <= np.asarray(hi_a)[:, None]), -1)
    found = bp.overlapping_jit(lo_a, hi_a, lo_b, hi_b, 4000)
    on = np.asarray(found.on)
    assert not bool(found.overflow)
    got = set(zip(np.asarray(found.a)[on].tolist(), np.asarray(found.b)[on].tolist()))
    assert got == set(zip(*map(np.ndarray.tolist, np.nonzero(ref))))
    same = bp.overlapping_jit(lo_a, hi_a, lo_a, hi_a, 4000, same=True)
    on = np.asarray(same.on)
    ref = np.all((np.asarray(lo_a)[:, None] <= np.asarray(hi_a)[None]) & (np.asarray(lo_a)[None] <= np.asarray(hi_a)[:, None]), -1)
    assert set(zip(np.asarray(same.a)[on].tolist(), np.asarray(same.b)[on].tolist())) == {
        (i, j) for i, j in zip(*np.nonzero(ref)) if i < j}


def _pair_list(found):
    on = np.asarray(found.on)
    return sorted(zip(np.asarray(found.a)[on].tolist(), np.asarray(found.b)[on].tolist()))


@pytest.mark.parametrize("packed_bits", [bp.PACKED_BITS, 0])
@pytest.mark.parametrize("hashed", ["xla", "two buckets"])
def test_broadphase_reports_each_pair_once(monkeypatch, packed_bits, hashed):
    """Both cell tables (bucket and box id packed in one sorted word, and a stable argsort for
    larger sets), with the real hash and with one under which most cells share a bucket: the
    found list, with multiplicity, is the brute-force one (a match counts only in the entry's
    home cell, and within one set each unordered pair is met from one side only)."""
    monkeypatch.setattr(bp, "PACKED_BITS", packed_bits)
    if hashed != "xla":
        monkeypatch.setattr(bp, "_hash", lambda cell: (jnp.sum(cell, axis=-1) % 2).astype(jnp.int32))
    rng = np.random.default_rng(7)
    lo_a, hi_a = _boxes(rng, 40, 0.08)
    lo_b, hi_b = _boxes(rng, 30, 0.08)
    # a fresh function per case: jit's trace cache does not see the patched module
    f = jax.jit(lambda *a, **k: bp.overlapping(*a, **k), static_argnames=("capacity", "same"))
    found = f(lo_a, hi_a, lo_b, hi_b, capacity=4000)
    ref = np.all((np.asarray(lo_a)[:, None] <= np.asarray(hi_b)[None]) & (np.asarray(lo_b)[None] <= np.asarray(hi_a)[:, None]), -1)
    assert not bool(found.overflow)
    assert _pair_list(found) == sorted(zip(*map(np.ndarray.tolist, np.nonzero(ref))))
    assert int(found.count) == int(ref.sum())
    same = f(lo_a, hi_a, lo_a, hi_a, capacity=4000, same=True)
    ref = np.all((np.asarray(lo_a)[:, None] <= np.asarray(hi_a)[None]) & (np.asarray(lo_a)[None] <= np.asarray(hi_a)[:, None]), -1)
    assert _pair_list(same) == sorted((int(i), int(j)) for i, j in zip(*np.nonzero(ref)) if i < j)


@pytest.mark.parametrize("packed_bits", [bp.PACKED_BITS, 0])
def test_broadphase_in_small_chunks_and_the_narrow_phase(monkeypatch, packed_bits):
    """The search walked 16 matches at a time (many passes of its loop) finds the
    brute-force pairs in the order of one pass; ``kept`` keeps those a test passes, in
    order, and says when they outnumber its slots."""
    rng = np.random.default_rng(11)
    lo_a, hi_a = _boxes(rng, 120, 0.15)
    lo_b, hi_b = _boxes(rng, 90, 0.15)
    monkeypatch.setattr(bp, "PACKED_BITS", packed_bits)
    f = jax.jit(lambda *a, **k: bp.overlapping(*a, **k), static_argnames=("capacity", "same"))
    whole = [f(lo_a, hi_a, lo_b, hi_b, capacity=4000), f(lo_a, hi_a, lo_a, hi_a, capacity=4000, same=True)]
    monkeypatch.setattr(bp, "CHUNK", 16)
    f = jax.jit(lambda *a, **k: bp.overlapping(*a, **k), static_argnames=("capacity", "same"))
    small = [f(lo_a, hi_a, lo_b, hi_b, capacity=4000), f(lo_a, hi_a, lo_a, hi_a, capacity=4000, same=True)]
    for one, many in zip(whole, small):
        assert int(one.count) > 3 * 16 and int(many.count) == int(one.count) and not bool(many.overflow)
        for u, v in ((one.a, many.a), (one.b, many.b), (one.on, many.on)):
            np.testing.assert_array_equal(np.asarray(u), np.asarray(v))
    ref = np.all((np.asarray(lo_a)[:, None] <= np.asarray(hi_b)[None]) & (np.asarray(lo_b)[None] <= np.asarray(hi_a)[:, None]), -1)
    assert _pair_list(small[0]) == sorted(zip(*map(np.ndarray.tolist, np.nonzero(ref))))
    found = small[0]
    on = np.asarray(found.on)
    a, b = np.asarray(found.a)[on], np.asarray(found.b)[on]
    want = np.stack([a, b, a + b, a * b], axis=1)[(a + b) % 3 == 0]

    def test(a, b):
        return jnp.stack([a, b, a + b, a * b], axis=1), (a + b) % 3 == 0

    k = jax.jit(lambda fd, cap: bp.kept(fd, test, cap, 4), static_argnums=1)
    got = k(found, 4000)
    assert int(got.count) == len(want) and not bool(got.overflow)
    np.testing.assert_array_equal(np.asarray(got.a)[np.asarray(got.on)], want)
    short = k(found, len(want) - 1)
    assert bool(short.overflow)
    np.testing.assert_array_equal(np.asarray(short.a), want[:-1])


def test_broadphase_overflow_is_reported():
    rng = np.random.default_rng(1)
    lo, hi = _boxes(rng, 200, 0.2)
    found = bp.overlapping_jit(lo, hi, lo, hi, 16, same=True)
    assert bool(found.overflow)
    on = np.asarray(found.on)
    a, b = np.asarray(found.a)[on], np.asarray(found.b)[on]  # what it kept are true pairs
    assert np.all((np.asarray(lo)[a] <= np.asarray(hi)[b]) & (np.asarray(lo)[b] <= np.asarray(hi)[a]))
    assert bool(bp.overlapping_jit(lo, hi, lo, hi, 40000, same=True).overflow) is False


def test_two_layers_closer_than_a_cell_do_not_overflow_the_search():
    """Two 32x32 layers 3 cm apart (``benchmarks/cloth_self_contact.py``): their cells
    (3.4 cm) hold both layers, and a fall of 5 mm or 2 cm moves boxes across cells' faces.
    The edge-edge box pairs are those at rest, with no overflow (with 8 matches a slot
    the search overflowed from 5 mm on)."""
    n = 31
    top = C.grid(n, 1 / n, origin=(-0.5, 0.98, -0.5)).rest
    low = C.grid(n, 1 / n, origin=(-0.49, 0.95, -0.49)).rest
    T = C.grid_triangles(n)
    c = C.from_mesh(np.concatenate([top, low]), np.concatenate([T, T + (n + 1) ** 2]), stiffness=1e3,
                    density=0.25, dtype=np.float32, self_contact=True)
    sc_ = build(c, 1.0)
    counts = []
    for fall in (0.0, 0.005, 0.02):
        dx = jnp.zeros_like(c.rest).at[:, 1].set(-fall)
        found = jax.jit(sp.candidates)(sc_, c.rest, dx).ee
        assert not bool(found.overflow), fall
        counts.append(int(found.count))
    assert counts[0] > 10000 and counts == [counts[0]] * 3


def test_additive_ccd_is_safe_and_close():
    """A point moving onto a triangle, and two crossing edges: the time returned is before
    the exact time of impact, within the separation target of it, and 1 when they miss."""
    rng = np.random.default_rng(3)
    K = 64
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 1]])
    p0 = np.stack([rng.uniform(0.05, 0.4, K), rng.uniform(0.1, 1.0, K), rng.uniform(0.05, 0.4, K)], -1)
    fall = rng.uniform(0.5, 3.0, K) * p0[:, 1]  # how far it falls (misses when short)
    assert np.sum(fall < 0.9 * p0[:, 1]) > 5
    X = np.concatenate([p0[:, None], np.broadcast_to(tri, (K, 3, 3))], axis=1)
    D = np.zeros_like(X)
    D[:, 0, 1] = -fall
    D[:, 1:] = rng.normal(scale=0.01, size=(K, 3, 3)) * 0  # the triangle at rest
    t = np.asarray(ccd.additive(jnp.asarray(X), jnp.asarray(D), point_triangle2, 1))
    exact = np.where(fall > p0[:, 1], p0[:, 1] / fall, 1.0)
    assert np.all(t <= exact + 1e-15)
    hit = fall > p0[:, 1]
    assert np.all(t[fall < 0.9 * p0[:, 1]] == 1.0)  # ends farther than the separation target: the whole step
    # the pair stops at no less than 10% of its distance, and not far before that
    assert np.all(p0[hit, 1] - t[hit] * fall[hit] >= 0.1 * p0[hit, 1] * (1 - 1e-12))
    assert np.all(p0[hit, 1] - t[hit] * fall[hit] <= 0.2 * p0[hit, 1])


@pytest.mark.parametrize("split", [1, 2])
def test_additive_ccds_reach_is_each_primitives_largest_relative_motion(split):
    """ACCD's ``l_p`` against NumPy: the largest vertex displacement of each primitive, the
    pair's mean displacement removed, summed over the two primitives."""
    D = np.random.default_rng(5).normal(size=(50, 4, 3))
    n = np.linalg.norm(D - D.mean(axis=1, keepdims=True), axis=-1)
    want = n[:, :split].max(axis=1) + n[:, split:].max(axis=1)
    np.testing.assert_allclose(np.asarray(ccd.reach(jnp.asarray(D), split)), want, rtol=1e-6)


def _layers_moving(seed, scale, down):
    """``(cloth, SelfContact, x, dx, pairs)``: two 4x4 layers 2 mm apart at rest, a random
    motion of ``scale`` (m) with the upper layer coming ``down`` (m), and its pairs."""
    c = _two_layers(n=4, gap=0.002, self_contact=True)
    sc_ = build(c, 10.0)
    x = c.rest
    rng = np.random.default_rng(seed)
    dx = jnp.asarray(rng.normal(scale=scale, size=x.shape)).at[: c.num_particles // 2, 1].add(-down)
    return c, sc_, x, dx, jax.jit(sp.pairs)(sc_, x, dx)


@pytest.mark.slow
def test_step_bound_in_chunks_equals_additive_ccd_over_every_slot():
    """The line search's bound over a pair set, taken a chunk at a time up to the last pair,
    is the least of additive CCD over every slot: on the broadphase's set, on one with
    empty slots between pairs, on one whose only pair sits alone in a last, partial chunk
    (it fails if that chunk is left out), and under ``vmap``."""
    c, sc_, x, dx, s = _layers_moving(5, 0.004, 0.004)
    assert 8 < int(jnp.sum(s.pt_on)) and 8 < int(jnp.sum(s.ee_on))

    @jax.jit
    def every_slot(s):
        """``(P,)`` additive CCD per point-triangle slot, and the least over every slot."""
        t = []
        for ids, on, dist2, split in ((s.pt, s.pt_on, point_triangle2, 1), (s.ee, s.ee_on, segment_segment2, 2)):
            D = jnp.where(on[:, None, None], dx[ids], 0.0)
            t.append(ccd.additive(sct._stand_in(x[ids], on), D, dist2, split, 1.0))
        return t[0], jnp.minimum(jnp.min(t[0]), jnp.min(t[1]))

    tp, want = every_slot(s)
    k = int(jnp.argmin(tp))
    assert float(want) < 1.0 and k >= 1
    gaps = dataclasses.replace(s, pt_on=s.pt_on.at[k - 1].set(False), ee_on=s.ee_on.at[2].set(False))
    lone = dataclasses.replace(s, pt_on=jnp.arange(s.pt_on.shape[0]) == k, ee_on=jnp.zeros_like(s.ee_on))
    bound = jax.jit(sct.step_bound, static_argnames="chunk")
    for pset, chunk in ((s, 3), (gaps, 3), (lone, k)):
        assert float(bound(sc_, pset, x, dx, 1.0, chunk=chunk)) == float(every_slot(pset)[1]) < 1.0
    both = jax.tree.map(lambda a, b: jnp.stack([a, b]), s, gaps)
    t = jax.vmap(lambda p: sct.step_bound(sc_, p, x, dx, 1.0, chunk=3))(both)
    assert [float(v) for v in t] == [float(every_slot(s)[1]), float(every_slot(gaps)[1])]


def test_newtons_sums_over_the_slots_in_use_equal_the_definition():
    """``summed`` (the barrier, its gradient and the force sizes over the slots in use, a
    chunk at a time) equals ``potential_and_forces`` and its ``jax.grad`` over every slot,
    and ``blocks`` laid out in chunks equal the blocks over every slot compacted: on a set
    with empty slots between its pairs, with pinned particles, NaN-free (an empty
    edge-edge slot's mollifier is 0/0: its derivative must not reach particle 0)."""
    c, sc_, x, dx, s = _layers_moving(3, 0.003, 0.002)
    n_pt, n_ee = int(jnp.sum(s.pt_on)), int(jnp.sum(s.ee_on))
    assert n_pt > 8 and n_ee > 8
    gaps = dataclasses.replace(s, pt_on=s.pt_on.at[3].set(False), ee_on=s.ee_on.at[1].set(False).at[n_ee - 2].set(False))
    y = x + 0.5 * dx
    free = jnp.ones((c.num_particles, 1), x.dtype).at[:5].set(0.0)
    for pset in (s, gaps):
        sc2 = dataclasses.replace(sc_, pairs=pset)
        (e0, f0), g0 = jax.jit(jax.value_and_grad(lambda z, sc2: sct.potential_and_forces(sc2, z, free),
                                                  has_aux=True))(y, sc2)
        e1, g1, f1 = jax.jit(sct.summed, static_argnames="chunk")(sc2, y, free, chunk=3)
        assert e0 > 0 and np.all(np.isfinite(np.asarray(g1)))
        np.testing.assert_allclose(e1, e0, rtol=1e-12)
        np.testing.assert_allclose(g1, g0, rtol=1e-10, atol=1e-12 * float(jnp.max(jnp.abs(g0))))
        np.testing.assert_allclose(f1, f0, rtol=1e-12, atol=0)
        B = jax.jit(sct.blocks, static_argnames="chunk")(sc2, y, free, chunk=3)
        ref = []
        for kind, ids, moves, X in sct._kinds(pset, y, free):
            d, w = sct._pair_distance(sc2, kind, X, ids)
            g = jax.grad(lambda Y: jnp.sum(sct._pair_distance(sc2, kind, Y, ids)[0]))(X).reshape(-1, 12)
            cc = np.asarray(jnp.where(moves, w * jnp.maximum(_d(barrier, 2)(d, sc2.dhat), 0.0), 0.0))
            g = np.asarray(g * jnp.repeat(free[ids, 0] > 0, 3, axis=1))
            ref += [(tuple(i), tuple(gi), ci) for i, gi, ci in zip(np.asarray(ids).tolist(), g.tolist(), cc) if ci != 0]
        k = int(B.count)
        assert k == len(ref) > 4 and B.ids.shape[0] % 3 == 0 and not np.any(np.asarray(B.c)[k:])
        assert [tuple(r) for r in np.asarray(B.ids)[:k].tolist()] == [r[0] for r in ref]
        np.testing.assert_allclose(np.asarray(B.g)[:k], np.array([r[1] for r in ref]), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(np.asarray(B.c)[:k], np.array([r[2] for r in ref]), rtol=1e-12)


def _set_of(s):
    """The pairs of a ``PairSet`` as two sets of id tuples."""
    return tuple({tuple(r) for r in np.asarray(ids)[np.asarray(on)].tolist()} for ids, on in ((s.pt, s.pt_on), (s.ee, s.ee_on)))


def test_a_motion_inside_the_region_draws_every_pair_from_the_candidates():
    """Candidates found for a motion grown by a margin serve a later motion whose ends stay
    in that region: ``holds`` says so, and the pairs drawn from them hold every pair a new
    search finds, and every pair within ``dhat`` at points sampled along the motion (by
    brute force).  A motion that leaves the region is searched anew.  It fails if the
    region is not grown (the later motion then leaves it) or if the candidates' boxes are
    not (pairs are missed)."""
    c = _two_layers(n=4, gap=0.002, self_contact=True)
    sc_ = build(c, 10.0)
    x = c.rest
    rng = np.random.default_rng(7)
    top = jnp.arange(c.num_particles) < c.num_particles // 2
    dx = jnp.asarray(rng.normal(scale=0.001, size=x.shape)).at[:, 1].add(jnp.where(top, -0.001, 0.0))
    grow = 2.0 * float(sc_.dhat)
    first = jax.jit(sp.pairs)(sc_, x, dx, grow)
    assert not bool(first.overflow)
    # a later motion from a point on the first one, the upper layer coming down: within
    # the margin of the first motion's boxes
    x2 = x + 0.7 * dx + jnp.asarray(rng.uniform(-0.15, 0.15, size=x.shape)).at[:, 1].add(jnp.where(top, -0.4, 0.0)) * grow
    dx2 = jnp.asarray(rng.uniform(-0.15, 0.15, size=x.shape)).at[:, 1].add(jnp.where(top, -0.25, 0.0)) * grow
    assert bool(sp.holds(first.source, x2, dx2))
    drawn = jax.jit(sp.draw)(sc_, first, x2, dx2, grow)
    assert drawn.source is not first.source and jnp.array_equal(drawn.source.lo, first.source.lo)
    fresh = _set_of(jax.jit(sp.pairs)(sc_, x2, dx2))
    got = _set_of(drawn)
    assert fresh[0] <= got[0] and fresh[1] <= got[1] and len(fresh[0]) > 4 and len(fresh[1]) > 4
    # (the later motion brings pairs within dhat that the first motion's own set lacks)
    assert not (fresh[0] <= _set_of(first)[0] and fresh[1] <= _set_of(first)[1])
    # brute force (with the distances checked against numpy references above)
    F, E = np.asarray(sc_.faces), np.asarray(sc_.edges)
    pi, fi = (a.ravel() for a in np.meshgrid(np.arange(len(x)), np.arange(len(F)), indexing="ij"))
    pt_ids = np.concatenate([pi[:, None], F[fi]], axis=1)
    pt_ids = pt_ids[np.all(pt_ids[:, 1:] != pt_ids[:, :1], axis=1)]
    ea, eb = np.triu_indices(len(E), 1)
    ee_ids = np.concatenate([E[ea], E[eb]], axis=1)
    ee_ids = ee_ids[[len(set(r)) == 4 for r in ee_ids.tolist()]]
    for t in np.linspace(0.0, 1.0, 5):
        y = x2 + t * dx2
        for ids, dist2, want in ((pt_ids, point_triangle2, got[0]), (ee_ids, segment_segment2, got[1])):
            near = np.asarray(dist2(*(y[ids[:, k]] for k in range(4)))) <= float(sc_.dhat) ** 2
            assert near.any() and {tuple(r) for r in ids[near].tolist()} <= want
    # a motion leaving the region is searched anew
    assert not bool(sp.holds(first.source, x2, dx2 + 3 * grow))
    far = jax.jit(sp.draw)(sc_, first, x2, dx2 + 3 * grow, grow)
    assert not jnp.array_equal(far.source.lo, first.source.lo)


def _two_layers(n=5, gap=0.04, colliders=(), dtype=np.float64, **kw):
    top = C.grid(n, 0.6 / n, origin=(-0.3, 0.6 + gap, -0.3)).rest
    low = C.grid(n, 0.6 / n, origin=(-0.27, 0.6, -0.28)).rest
    T1 = C.grid_triangles(n)
    V = np.concatenate([top, low])
    T = np.concatenate([T1, T1 + (n + 1) ** 2])
    return C.from_mesh(V, T, stiffness=300.0, density=0.3, dtype=dtype, colliders=colliders, **kw)


def test_bad_inputs_raise():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [0.3, -0.5, 0.3], [0.3, 0.5, 0.3], [0.4, 0.5, 0.2]], float)
    T = np.array([[0, 1, 2], [3, 4, 5]])
    with pytest.raises(ValueError, match=r"rest shape intersects itself: edge \d+ \(particles \[3, 4\]\).*triangle 0"):
        C.from_mesh(V, T, self_contact=True)
    ok = C.from_mesh(V + np.array([0, 0, 0, 0, 1, 0])[:, None] * 0 + np.r_[np.zeros((3, 3)), np.tile([0, 1.0, 0], (3, 1))],
                     T, self_contact=True)
    bad = C.State(jnp.asarray(V), jnp.zeros((6, 3)))
    with pytest.raises(ValueError, match="state intersects itself"):
        C.step(ok, bad, 1 / 60)
    with pytest.raises(ValueError, match="needs the scene's triangles"):
        C.replace(C.grid(3), self_contact=True)
    with pytest.raises(ValueError, match="needs ImplicitEuler"):
        C.step(ok, C.State.at_rest(ok), 1 / 60, C.ExplicitEuler())
    with pytest.raises(ValueError, match="BDF2"):
        C.step(ok, C.State.at_rest(ok), 1 / 60, C.BDF2())
    with pytest.raises(ValueError, match="contact_faces ids"):
        C.replace(C.grid(1), self_contact=True, contact_faces=np.array([[0, 1, 7]]))
    with pytest.raises(ValueError, match="self_contact_pairs"):
        C.grid(2, self_contact=True, self_contact_pairs=-3)


def test_off_compiles_no_self_contact_code():
    """Without ``self_contact`` the step holds no broadphase (its cell hash and prefix sum)
    and no barrier (its log); with it, it does."""
    base = C.grid(3, 0.2)
    names = lambda c: {e.primitive.name for e in all_eqns(step_jaxpr(c, C.ImplicitEuler()))}  # noqa: E731
    off, on = names(base), names(C.grid(3, 0.2, self_contact=True))
    marks = {"xor", "cumsum", "log"}
    assert not marks & off and marks <= on
    assert names(C.replace(C.grid(3, 0.2, self_contact=True), self_contact=False)) == off


def test_the_independent_check_sees_crossings():
    """The numpy triangle-triangle test: crossing, touching, coplanar overlapping, apart."""
    P = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 1]])
    cases = {
        "crossing": (np.array([[0.2, -0.5, 0.2], [0.2, 0.5, 0.2], [0.3, 0.5, 0.1]]), True),
        "touching": (np.array([[0.2, 0, 0.2], [0.2, 0.5, 0.2], [0.3, 0.5, 0.1]]), True),
        "coplanar": (np.array([[0.1, 0, 0.1], [2, 0, 0.1], [0.1, 0, 2]]), True),
        "above": (np.array([[0.2, 1e-9, 0.2], [0.2, 0.5, 0.2], [0.3, 0.5, 0.1]]), False),
        "beside": (np.array([[0.6, 0, 0.6], [2, 0, 0.6], [0.6, 0, 2]]), False),
    }
    for name, (Q, want) in cases.items():
        assert bool(triangle_pairs_intersect(P[None], Q[None])[0]) == want, name


# ---------------------------------------------------------------- scenes

DT = 1 / 60


def _min_gap(x, c):
    """The least distance between the two layers' particles and the other layer's
    triangles, at positions ``x (N, 3)`` (numpy, float64)."""
    x = np.asarray(x, np.float64)
    half = x.shape[0] // 2
    F = np.asarray(c.contact_faces)
    low = F[F.min(1) >= half]
    P = x[:half][:, None]
    T = x[low][None]
    d = point_triangle2(jnp.asarray(np.broadcast_to(P, (half, len(low), 3))), *[jnp.asarray(np.broadcast_to(T[:, :, i], (half, len(low), 3))) for i in range(3)])
    return float(np.sqrt(np.min(np.asarray(d))))


def _check_frames(states, c):
    """Every returned frame: no two triangles without a common vertex intersect."""
    X = np.asarray(states.x, np.float64)
    bad = [k for k in range(X.shape[0]) if self_intersections(X[k], c.contact_faces)]
    assert not bad, f"frames {bad} intersect"


def test_a_self_contact_rollout_keeps_two_small_layers_apart():
    """The fast tier's self-contact rollout: two 3x3-cell layers dropped onto a sphere
    (float32 defaults) for 0.5 s; the upper one lands on the lower one, no frame has two
    triangles crossing (the independent check), and every step is taken and converged."""
    sphere = C.Sphere(center=(0.0, 0.25, 0.0), radius=0.25)
    c = _two_layers(n=3, colliders=(sphere,), dtype=np.float32, self_contact=True)
    states, info = C.rollout(c, C.State.at_rest(c), DT, 30)
    _check_frames(states, c)
    assert bool(np.all(info.stable)) and bool(np.all(info.converged)) and not bool(np.any(info.pair_overflow))
    assert _min_gap(states.x[-1], c) < 2 * float(c.contact_gap)  # they met


@pytest.mark.slow
def test_two_layers_on_a_sphere_never_intersect():
    """Two layers dropped onto a sphere (float32, the default dtype's scene): the upper
    one lands on the lower one, every frame is free of intersections, every step is
    taken and converged."""
    sphere = C.Sphere(center=(0.0, 0.25, 0.0), radius=0.25)
    c = _two_layers(colliders=(sphere,), dtype=np.float32, self_contact=True)
    states, info = C.rollout(c, C.State.at_rest(c), DT, 45)
    _check_frames(states, c)
    assert bool(np.all(info.stable)) and float(np.mean(info.converged)) == 1.0
    assert not bool(np.any(info.pair_overflow))
    # the layers did meet: the upper layer's particles come within 2 dhat of the lower one
    assert min(_min_gap(states.x[k], c) for k in (20, 30, 44)) < 2 * float(c.contact_gap)


@pytest.mark.slow
def test_strip_piling_onto_itself_never_intersects():
    """A strip standing on its end on the floor falls, buckles and piles onto itself."""
    n, w, spacing = 12, 3, 0.04
    V = np.stack(np.meshgrid(np.arange(w) * spacing, np.arange(n + 1) * spacing, indexing="ij"), -1).reshape(-1, 2)
    V = np.stack([V[:, 0], 0.01 + V[:, 1], 0.002 * np.sin(7 * V[:, 1])], -1)  # upright, slightly bent
    idx = np.arange(w * (n + 1)).reshape(w, n + 1)
    T = np.concatenate([np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:]], -1).reshape(-1, 3),
                        np.stack([idx[:-1, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 3)])
    floor = C.Plane(normal=(0.0, 1.0, 0.0), offset=0.0, friction=0.3)
    c = C.from_mesh(V, T, stiffness=200.0, bending=0.5, density=0.2, colliders=(floor,), self_contact=True)
    states, info = C.rollout(c, C.State.at_rest(c), DT, 40)
    _check_frames(states, c)
    assert bool(np.all(info.stable)) and float(np.mean(info.converged)) >= 0.95
    assert float(np.max(states.x[-1, :, 1])) < 0.15  # the 0.49 m strip has folded down


@pytest.mark.slow
def test_cloth_over_a_thin_rod_never_intersects():
    """A cloth draped over a thin rod folds down on both sides without passing through itself."""
    rod = C.Capsule(a=(-0.5, 0.3, 0.0), b=(0.5, 0.3, 0.0), radius=0.01, friction=0.2)
    c = C.grid(6, 0.05, origin=(-0.15, 0.33, -0.15), mass=0.01, stiffness=80.0, damping=0.0, gravity=9.8, pins=[],
               colliders=(rod,), self_contact=True)
    states, info = C.rollout(c, C.State.at_rest(c), DT, 40)
    _check_frames(states, c)
    assert bool(np.all(info.stable)) and float(np.mean(info.converged)) >= 0.95


@pytest.mark.slow
@settings(max_examples=3, deadline=None)
@given(dx=st.floats(-0.1, 0.1), dz=st.floats(-0.1, 0.1), speed=st.floats(0.0, 2.0))
def test_random_drops_never_intersect(dx, dz, speed):
    """The upper layer shifted and thrown down at random (the same compiled program as
    the sphere scene)."""
    sphere = C.Sphere(center=(0.0, 0.25, 0.0), radius=0.25)
    c = _two_layers(colliders=(sphere,), dtype=np.float32, self_contact=True)
    half = c.num_particles // 2
    x = c.rest.at[:half].add(jnp.array([dx, 0.0, dz], jnp.float32))
    v = jnp.zeros_like(x).at[:half, 1].set(-speed)
    states, info = C.rollout(c, C.State(x, v), DT, 45)
    _check_frames(states, c)
    assert bool(np.all(info.stable))


@pytest.mark.slow
def test_capacity_overflow_is_reported_not_silent():
    """Too few pair slots: the step says so, and is not converged."""
    c = _two_layers(gap=0.0005, self_contact=True, self_contact_pairs=2)
    assert 0.0005 < float(c.contact_gap)  # the layers start within the barrier: many pairs
    _, info = C.step(c, C.State.at_rest(c), DT, C.ImplicitEuler(max_substep_depth=0))
    assert bool(info.pair_overflow) and not bool(info.converged)


@pytest.mark.slow
def test_implicit_derivative_through_the_barrier():
    """The derivative of a step's end positions with respect to gravity, with the upper
    layer resting on the barrier: implicit-function derivative against central finite
    differences (float64)."""
    c = _two_layers(n=2, gap=0.0008, self_contact=True, contact_gap=0.001)
    low = np.zeros(c.num_particles, bool)
    low[c.num_particles // 2:] = True
    c = C.replace(c, pinned=jnp.asarray(low))
    # the derivative's PCG solved to 1e-10: at CG's default 1e-6 its error on this stiff
    # barrier is up to 1.2e-5 relative, and where in that range it falls depends on the
    # machine's rounding (Cholesky and PCG at 1e-10 agree to 1e-10)
    integ = C.ImplicitEuler(max_substep_depth=0, rtol=1e-12, newton_iters=200, linear_solver=C.CG(tol=1e-10))

    def loss(g):
        s, info = C.step(C.replace(c, gravity=jnp.array([0.0, -g, 0.0])), C.State.at_rest(c), DT, integ)
        return jnp.sum(s.x[:, 1] * jnp.arange(c.num_particles)), info

    (val, info), grad = jax.value_and_grad(loss, has_aux=True)(9.8)
    assert bool(info.converged)
    eps = 1e-4
    fd = (loss(9.8 + eps)[0] - loss(9.8 - eps)[0]) / (2 * eps)
    assert float(grad) == pytest.approx(float(fd), rel=1e-5)
    assert abs(float(grad)) > 1e-6  # the barrier holds the layer: the end positions still depend on g


@pytest.mark.slow
def test_batch_rollout_equals_rollouts():
    """Two scenes with self-contact in one ``batch_rollout``: each equals its own rollout."""
    sphere = C.Sphere(center=(0.0, 0.25, 0.0), radius=0.25)
    a = _two_layers(n=3, colliders=(sphere,), self_contact=True)
    b = C.replace(a, stiffness=a.stiffness * 2)
    states, infos = C.batch_rollout([a, b], C.State.at_rest(a), DT, 30)
    assert bool(np.all(infos.converged))
    for k, scene in enumerate((a, b)):
        alone, _ = C.rollout(scene, C.State.at_rest(scene), DT, 30)
        np.testing.assert_allclose(states.x[k], alone.x, rtol=0, atol=1e-10)
    with pytest.raises(ValueError, match="self_contact"):
        C.stack_scenes([a, C.replace(a, self_contact=False)])
