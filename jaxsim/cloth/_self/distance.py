"""Squared distances between mesh primitives, and IPC's edge–edge mollifier.

Every distance is the minimum over the pieces where the closest points can lie (Li et al.
2020, §3, "distance types"): for a point and a triangle, the plane when the point projects
inside the triangle, else the nearest of the three edges; for two segments, the two
lines when their closest points lie inside both segments, else the nearest of the four
point–segment distances.  Each piece is smooth where it is the minimum, so ``jax.grad``
of the minimum is that of the active piece.  Pieces that are not defined (a degenerate
triangle's plane, parallel lines) are masked by a double ``where``, so derivatives stay
NaN-free.  Each piece also gives its nearest points, and :func:`pair_distance2`, which
the barrier differentiates, takes its derivative from them.

Points are ``(x, y, z)`` tuples of equally shaped arrays (structure of arrays): written
per coordinate, the derivatives of a batch of pairs compile to a few fused loops instead
of a slice and a pad per coordinate use.  The public functions take ``(..., 3)`` arrays.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..._dtype import tiny
from ..._fusion import materialized


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _soa(v):
    return (v[..., 0], v[..., 1], v[..., 2])


def _point_segment(p, a, b):
    """``(d2, diff, t)``: ``|p - q|^2``, ``p - q`` and ``t`` for the nearest point
    ``q = a + t (b - a)`` of the segment ``ab``."""
    e = _sub(b, a)
    ee = _dot(e, e)
    ok = ee > tiny(ee.dtype)
    r = _sub(p, a)
    t = jnp.clip(jnp.where(ok, _dot(r, e) / jnp.where(ok, ee, 1.0), 0.0), 0.0, 1.0)
    d = (r[0] - t * e[0], r[1] - t * e[1], r[2] - t * e[2])
    return _dot(d, d), d, t


def _least(pieces):
    """The piece ``(d2, diff, coef)`` with the least ``d2`` (the first on ties)."""
    best = pieces[0]
    for piece in pieces[1:]:
        take = piece[0] < best[0]
        best = jax.tree.map(lambda u, v: jnp.where(take, u, v), piece, best)
    return best


def _scaled(s, v):
    return (s * v[0], s * v[1], s * v[2])


def _point_triangle(p, a, b, c):
    """``(d2, diff, coef)`` for the point ``p`` and the triangle ``abc``: the squared
    distance, the difference ``p - q`` to the nearest point ``q`` and the vertices' factors
    ``(1, -wa, -wb, -wc)`` with ``q = wa a + wb b + wc c``."""
    e0, e1 = _sub(b, a), _sub(c, a)
    n = _cross(e0, e1)
    nn = _dot(n, n)
    ok = nn > tiny(nn.dtype) * (_dot(e0, e0) * _dot(e1, e1) + tiny(nn.dtype))
    nns = jnp.where(ok, nn, 1.0)
    r = _sub(p, a)
    # barycentric coordinates of p's projection (Ericson 2004, 3.4)
    u = _dot(_cross(r, e1), n) / nns  # weight of b
    v = _dot(_cross(e0, r), n) / nns  # weight of c
    inside = ok & (u >= 0) & (v >= 0) & (u + v <= 1)
    rn = _dot(r, n)
    one, zero = jnp.ones_like(u), jnp.zeros_like(u)
    plane = (jnp.where(inside, rn**2 / nns, jnp.inf), _scaled(rn / nns, n), (one, u + v - 1.0, -u, -v))
    pieces = [plane]
    for (i, j), (s, t) in (((1, 2), (a, b)), ((2, 3), (b, c)), ((3, 1), (c, a))):
        d2, d, w = _point_segment(p, s, t)
        coef = [one, zero, zero, zero]
        coef[i], coef[j] = w - 1.0, -w
        pieces.append((d2, d, tuple(coef)))
    return _least(pieces)


def _segment_segment(a0, a1, b0, b1):
    """``(d2, diff, coef)`` for the segments ``a0 a1`` and ``b0 b1``: the squared distance,
    the difference ``pa - pb`` of the nearest points ``pa = a0 + s (a1 - a0)``,
    ``pb = b0 + t (b1 - b0)`` and the vertices' factors ``(1 - s, s, t - 1, -t)``."""
    ea, eb, r = _sub(a1, a0), _sub(b1, b0), _sub(a0, b0)
    n = _cross(ea, eb)
    nn = _dot(n, n)
    ok = nn > 1e-10 * _dot(ea, ea) * _dot(eb, eb) + tiny(nn.dtype)  # not parallel (else an endpoint is nearest)
    nns = jnp.where(ok, nn, 1.0)
    # the lines' closest parameters (a0 + s ea, b0 + t eb)
    s = _dot(_cross(eb, r), n) / nns
    t = _dot(_cross(ea, r), n) / nns
    inner = ok & (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
    rn = _dot(r, n)
    one, zero = jnp.ones_like(s), jnp.zeros_like(s)
    pieces = [(jnp.where(inner, rn**2 / nns, jnp.inf), _scaled(rn / nns, n), (1.0 - s, s, t - 1.0, -t))]
    for end, (p, q0, q1) in enumerate(((a0, b0, b1), (a1, b0, b1))):  # an end of a, nearest on b
        d2, d, w = _point_segment(p, q0, q1)
        pieces.append((d2, d, (one - end, zero + end, w - 1.0, -w)))
    for end, (p, q0, q1) in enumerate(((b0, a0, a1), (b1, a0, a1))):  # an end of b, nearest on a
        d2, d, w = _point_segment(p, q0, q1)
        pieces.append((d2, _scaled(-1.0, d), (1.0 - w, w, end - one, zero - end)))
    return _least(pieces)


def point_segment2_soa(p, a, b):
    """``|p - q|^2`` for the nearest point ``q`` of the segment ``ab`` (points as tuples)."""
    return _point_segment(p, a, b)[0]


def point_triangle2_soa(p, a, b, c):
    """Squared distance from the point ``p`` to the triangle ``abc`` (points as tuples)."""
    return _point_triangle(p, a, b, c)[0]


def segment_segment2_soa(a0, a1, b0, b1):
    """Squared distance between the segments ``a0 a1`` and ``b0 b1`` (points as tuples)."""
    return _segment_segment(a0, a1, b0, b1)[0]


def columns(X):
    """The four points of the pairs ``X (P, 4, 3)`` as ``(x, y, z)`` tuples of ``(P,)`` arrays."""
    return [(X[:, i, 0], X[:, i, 1], X[:, i, 2]) for i in range(4)]


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def pair_distance2(kind: int, X):
    """``(P,)`` squared distances (m^2) of the pairs ``X (P, 4, 3)``: point–triangle
    ``(p, a, b, c)`` for ``kind`` 0, segment–segment ``(a0, a1, b0, b1)`` for 1.

    Its derivative is that of the nearest points' distance with the points held (the
    minimum's envelope: ``2 coef_i (p_a - p_b)`` at vertex ``i``), built from the same pass
    that finds them and written once (``_fusion.materialized``); ``jax.grad`` through the
    pieces' ``where`` and ``minimum`` compiles to loops that each recompute the whole
    search, one per output coordinate (docs/notebook.md, 2026-12-06).  The rule is itself
    differentiable, so second derivatives are exact too."""
    return (_point_triangle if kind == 0 else _segment_segment)(*columns(X))[0]


@pair_distance2.defjvp
def _pair_distance2_jvp(kind, primals, tangents):
    (X,), (dX,) = primals, tangents
    d2, diff, coef = (_point_triangle if kind == 0 else _segment_segment)(*columns(X))
    R = materialized(jnp.stack([*diff, *coef], axis=1))  # (P, 7)
    G = 2.0 * R[:, 3:, None] * R[:, None, :3]  # (P, 4, 3)
    return d2, jnp.sum(G * dX, axis=(1, 2))


def mollifier_soa(a0, a1, b0, b1, eps_x):
    """IPC's edge–edge mollifier ``m(c)`` (§4.3), ``c = |ea x eb|^2``: ``(2 - c/eps_x) c/eps_x``
    below ``eps_x``, 1 beyond.  It takes the barrier of nearly parallel edges smoothly to 0,
    where the edge–edge distance stops being smooth."""
    n = _cross(_sub(a1, a0), _sub(b1, b0))
    c = _dot(n, n)
    q = c / eps_x
    return jnp.where(c < eps_x, (2.0 - q) * q, 1.0)


def point_segment2(p, a, b):
    """``|p - q|^2`` (m^2) for the nearest point ``q`` of the segment ``ab``; ``(..., 3)`` inputs."""
    return point_segment2_soa(_soa(p), _soa(a), _soa(b))


def point_triangle2(p, a, b, c):
    """Squared distance (m^2) from the points ``p`` to the triangles ``abc``, all ``(..., 3)``."""
    return point_triangle2_soa(_soa(p), _soa(a), _soa(b), _soa(c))


def segment_segment2(a0, a1, b0, b1):
    """Squared distance (m^2) between the segments ``a0 a1`` and ``b0 b1``, all ``(..., 3)``."""
    return segment_segment2_soa(_soa(a0), _soa(a1), _soa(b0), _soa(b1))


def mollifier(a0, a1, b0, b1, eps_x):
    """:func:`mollifier_soa` on ``(..., 3)`` inputs."""
    return mollifier_soa(_soa(a0), _soa(a1), _soa(b0), _soa(b1), eps_x)
