"""The rank-one Hessian blocks ``c g g^T`` (self-contact pairs, wind): compaction to the acting
groups and the chunked product give the same blocks, under ``jit`` and ``vmap``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim.cloth._rank_one import RankOne, combine

from _helpers import compacted


def _random(rng, E, k, N, acting):
    ids = np.stack([rng.choice(N, size=k, replace=False) for _ in range(E)]).astype(np.int32)  # distinct, as in a pair
    g = rng.normal(size=(E, 3 * k))
    c = np.where(rng.uniform(size=E) < acting, rng.uniform(0.5, 2.0, size=E), 0.0)
    return RankOne(jnp.asarray(ids), jnp.asarray(g), jnp.asarray(c))


def _dense_ref(r: RankOne, N):
    """The blocks assembled in NumPy, group by group."""
    H = np.zeros((3 * N, 3 * N))
    for ids, g, c in zip(np.asarray(r.ids), np.asarray(r.g), np.asarray(r.c)):
        rows = (ids[:, None] * 3 + np.arange(3)).reshape(-1)
        H[np.ix_(rows, rows)] += c * np.outer(g, g)
    return H


@pytest.mark.parametrize("acting", [0.0, 0.05, 0.6, 1.0])
def test_compacted_blocks_are_the_same_blocks(acting):
    rng = np.random.default_rng(3)
    N, chunk = 30, 16
    r = _random(rng, 100, 4, N, acting)
    q = jax.jit(compacted, static_argnums=1)(r, chunk)
    assert q.ids.shape[0] % chunk == 0 and int(q.count) == int(np.sum(np.asarray(r.c) != 0))
    assert np.all(np.asarray(q.c)[int(q.count):] == 0)
    H = _dense_ref(r, N)
    v = rng.normal(size=(N, 3))
    for blocks in (r, q):
        np.testing.assert_allclose(np.asarray(jax.jit(RankOne.matvec)(blocks, v)).reshape(-1), H @ v.reshape(-1),
                                   rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.asarray(blocks.dense(N)), H, rtol=1e-12, atol=1e-12)
        diag = np.stack([H[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(N)])
        np.testing.assert_allclose(np.asarray(blocks.diagonal(N)), diag, rtol=1e-12, atol=1e-12)


def test_combined_with_a_compacted_group_is_the_sum():
    rng = np.random.default_rng(4)
    N, chunk = 25, 8
    wind = _random(rng, 13, 3, N, 1.0)  # triangles: every group acts
    pairs = compacted(_random(rng, 40, 4, N, 0.2), chunk)
    v = rng.normal(size=(N, 3))
    ref = np.asarray(wind.matvec(v)) + np.asarray(pairs.matvec(v))
    for both in (combine(wind, pairs), combine(pairs, wind)):
        assert both.count is not None and both.ids.shape[0] % chunk == 0
        np.testing.assert_allclose(np.asarray(both.matvec(v)), ref, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.asarray(both.dense(N)), _dense_ref(wind, N) + _dense_ref(pairs, N),
                                   rtol=1e-12, atol=1e-12)


def test_chunked_product_under_vmap_equals_a_loop():
    """A batch of scenes with different numbers of acting groups (the loop's trip count)."""
    rng = np.random.default_rng(5)
    N, chunk = 20, 8
    rs = [compacted(_random(rng, 48, 4, N, a), chunk) for a in (0.0, 0.1, 0.5, 1.0)]
    vs = rng.normal(size=(4, N, 3))
    batch = jax.tree.map(lambda *x: jnp.stack(x), *rs)
    got = jax.jit(jax.vmap(RankOne.matvec))(batch, vs)
    for r, v, out in zip(rs, vs, np.asarray(got)):
        np.testing.assert_allclose(out, np.asarray(r.matvec(v)), rtol=1e-12, atol=1e-12)
