"""The rotation that best aligns weighted vector pairs (Wahba's problem), by Horn's quaternion method.

Horn (1987), "Closed-form solution of absolute orientation using unit quaternions",
§4: the unit quaternion ``q`` maximising ``sum_k w_k b_k . (q a_k q*)`` is the
eigenvector of the largest eigenvalue of the symmetric 4x4 matrix ``N`` built from
``S = sum_k w_k a_k b_k^T``.  For IK this is exact least squares: turning the subtree
below a joint by ``R`` minimises ``sum_k w_k |R a_k - b_k|^2`` (``a_k`` joint-to-effector,
``b_k`` joint-to-target) when it maximises ``sum_k w_k b_k . R a_k``.

The eigenvector is taken by repeated squaring of ``M = (N + s I) / 2s`` (``s =
sum w |a||b|`` bounds every eigenvalue, so ``M`` is positive semidefinite), renormalised
by its trace: after ``n`` squarings the other eigenvalues are damped by
``(lambda_2/lambda_1)^(2^n)``.  The answer is ``M^(2^n) e_0``, the projection of the
identity onto the top eigenspace: where the optimum is not unique (one vector pair, or
collinear pairs) this is the optimal rotation nearest to no rotation, which for one
pair is exactly the shortest arc.  Plain elementwise arithmetic on component tuples:
batched, NaN-free in value and gradient (no eigendecomposition, no division by an
eigenvalue gap).
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax

from .._dtype import tiny
from . import quat as _quat

#: Squarings of ``M``: other eigenvalues are damped by ``ratio ** 2**SQUARINGS``.
SQUARINGS = 12


_UPPER = [(i, j) for i in range(4) for j in range(i, 4)]


def _square(m):
    """Square of a symmetric 4x4 matrix given as a dict of its 10 upper entries."""
    g = lambda i, j: m[(i, j) if i <= j else (j, i)]  # noqa: E731
    return {(i, j): sum(g(i, k) * g(k, j) for k in range(4)) for i, j in _UPPER}


def _power(m, n):
    """``M^(2^n)`` renormalised to unit trace, by ``n`` squarings in a ``fori_loop`` (one
    small loop body to compile, however many joints call it)."""
    dt = jnp.result_type(*m.values())

    def body(_, a):
        sq = _square(dict(zip(_UPPER, a)))
        tr = sq[(0, 0)] + sq[(1, 1)] + sq[(2, 2)] + sq[(3, 3)]
        r = 1.0 / jnp.where(tr > tiny(dt), tr, 1.0)
        return jnp.stack([sq[k] * r for k in _UPPER])

    a = lax.fori_loop(0, n, body, jnp.stack(jnp.broadcast_arrays(*[m[k] for k in _UPPER])))
    return dict(zip(_UPPER, a))


def best_rotation(a, b, w):
    """Unit quaternion ``q`` maximising ``sum_k w_k b_k . rotate(q, a_k)``.

    Args:
      a, b: lists of ``K`` vector tuples (each component of batch shape ``B``).
      w: list of ``K`` non-negative weights (scalars or arrays broadcasting to ``B``).

    Returns:
      Quaternion tuple (w, x, y, z) with ``w >= 0``; the identity where every product
      ``w_k |a_k| |b_k|`` is zero.
    """
    S = [[sum(wk * ak[i] * bk[j] for ak, bk, wk in zip(a, b, w)) for j in range(3)] for i in range(3)]
    (xx, xy, xz), (yx, yy, yz), (zx, zy, zz) = S
    s = sum(wk * _quat.safe_norm(ak) * _quat.safe_norm(bk) for ak, bk, wk in zip(a, b, w))
    dt = jnp.result_type(s)
    ok = s > tiny(dt)
    inv = 1.0 / jnp.where(ok, 2.0 * s, 1.0)
    N = {(0, 0): xx + yy + zz, (0, 1): yz - zy, (0, 2): zx - xz, (0, 3): xy - yx,
         (1, 1): xx - yy - zz, (1, 2): xy + yx, (1, 3): zx + xz,
         (2, 2): -xx + yy - zz, (2, 3): yz + zy,
         (3, 3): -xx - yy + zz}
    m = {k: (v + (s if k[0] == k[1] else 0.0)) * inv for k, v in N.items()}
    m = _power(m, SQUARINGS)
    g = lambda i, j: m[(i, j) if i <= j else (j, i)]  # noqa: E731
    cols = [tuple(g(i, j) for i in range(4)) for j in range(4)]
    # the identity's projection, unless the optimum is (nearly) a half-turn: then the
    # column of the largest diagonal entry (trace 1, so that entry is >= 1/4)
    best, best_d = cols[3], g(3, 3)
    for j in (2, 1):
        better = g(j, j) > best_d
        best, best_d = _quat.where(better, cols[j], best), jnp.maximum(best_d, g(j, j))
    q = _quat.where(g(0, 0) >= 1e-3, cols[0], best)
    q = _quat.where(q[0] < 0, _quat.scale(-1.0, q), q)
    n = _quat.safe_norm(q)
    good = ok & (n > tiny(dt))
    q = _quat.scale(1.0 / jnp.where(good, n, 1.0), q)
    return _quat.where(good, q, _quat.identity(jnp.shape(q[0]), dt))
