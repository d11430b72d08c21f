"""Squared distances between mesh primitives, and IPC's edge–edge mollifier.

Every distance is the minimum over the pieces where the closest points can lie (Li et al.
2020, §3, "distance types"): for a point and a triangle, the plane when the point projects
inside the triangle, else the nearest of the three edges; for two segments, the two
lines when their closest points lie inside both segments, else the nearest of the four
point–segment distances.  Each piece is smooth where it is the minimum, so ``jax.grad``
of the minimum is that of the active piece.  Pieces that are not defined (a degenerate
triangle's plane, parallel lines) are masked by a double ``where``, so derivatives stay
NaN-free.

Points are ``(x, y, z)`` tuples of equally shaped arrays (structure of arrays): written
per coordinate, the derivatives of a batch of pairs compile to a few fused loops instead
of a slice and a pad per coordinate use.  The public functions take ``(..., 3)`` arrays.
"""

from __future__ import annotations

import jax.numpy as jnp

from ..._dtype import tiny


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _soa(v):
    return (v[..., 0], v[..., 1], v[..., 2])


def point_segment2_soa(p, a, b):
    """``|p - q|^2`` for the nearest point ``q`` of the segment ``ab`` (points as tuples)."""
    e = _sub(b, a)
    ee = _dot(e, e)
    ok = ee > tiny(ee.dtype)
    r = _sub(p, a)
    t = jnp.clip(jnp.where(ok, _dot(r, e) / jnp.where(ok, ee, 1.0), 0.0), 0.0, 1.0)
    d = (r[0] - t * e[0], r[1] - t * e[1], r[2] - t * e[2])
    return _dot(d, d)


def point_triangle2_soa(p, a, b, c):
    """Squared distance from the point ``p`` to the triangle ``abc`` (points as tuples)."""
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
    plane = jnp.where(inside, _dot(r, n) ** 2 / nns, jnp.inf)
    edges = jnp.minimum(jnp.minimum(point_segment2_soa(p, a, b), point_segment2_soa(p, b, c)),
                        point_segment2_soa(p, c, a))
    return jnp.minimum(plane, edges)


def segment_segment2_soa(a0, a1, b0, b1):
    """Squared distance between the segments ``a0 a1`` and ``b0 b1`` (points as tuples)."""
    ea, eb, r = _sub(a1, a0), _sub(b1, b0), _sub(a0, b0)
    n = _cross(ea, eb)
    nn = _dot(n, n)
    ok = nn > 1e-10 * _dot(ea, ea) * _dot(eb, eb) + tiny(nn.dtype)  # not parallel (else an endpoint is nearest)
    nns = jnp.where(ok, nn, 1.0)
    # the lines' closest parameters (a0 + s ea, b0 + t eb)
    s = _dot(_cross(eb, r), n) / nns
    t = _dot(_cross(ea, r), n) / nns
    inner = ok & (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
    lines = jnp.where(inner, _dot(r, n) ** 2 / nns, jnp.inf)
    ends = jnp.minimum(jnp.minimum(point_segment2_soa(a0, b0, b1), point_segment2_soa(a1, b0, b1)),
                       jnp.minimum(point_segment2_soa(b0, a0, a1), point_segment2_soa(b1, a0, a1)))
    return jnp.minimum(lines, ends)


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
