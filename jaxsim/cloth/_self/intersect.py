"""Does a mesh intersect itself?  Edge–triangle crossings in float64, outside ``jit``.

Two triangles without a common vertex intersect exactly when an edge of one meets the
other, so every edge is tested against every triangle it shares no vertex with whose box
it touches (candidates from ``_self.broadphase``).  The segment's ends on either side of
(or on) the triangle's plane, by the sign of an orientation determinant, and the point
where it meets the plane inside the triangle; a segment in the triangle's plane is
tested in 2D.  Touching counts as intersecting.
"""

from __future__ import annotations

import numpy as np


def _orient(a, b, c, d):
    """Six times the signed volume of ``abcd`` (``(..., 3)`` each)."""
    return np.einsum("...i,...i->...", np.cross(b - a, c - a), d - a)


def _segment_triangle(p, q, a, b, c, tol):
    """``(P,)`` bool: segment ``pq`` meets triangle ``abc`` (all ``(P, 3)``).

    Ends on opposite sides of the plane (or one on it): the point where the segment meets
    the plane, tested inside the triangle by its barycentric coordinates.  Both ends on
    the plane (within ``tol``): the 2D test."""
    sp, sq = _orient(a, b, c, p), _orient(a, b, c, q)
    sp = np.where(np.abs(sp) <= tol, 0.0, sp)
    sq = np.where(np.abs(sq) <= tol, 0.0, sq)
    planar = (sp == 0) & (sq == 0)
    crosses = (np.sign(sp) * np.sign(sq) <= 0) & ~planar
    den = np.where(crosses, sp - sq, 1.0)
    t = np.where(crosses, sp / den, 0.0)
    x = p + t[:, None] * (q - p)
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    u = np.einsum("ij,ij->i", np.cross(x - a, c - a), n) / nn  # weight of b
    v = np.einsum("ij,ij->i", np.cross(b - a, x - a), n) / nn  # weight of c
    eps = 1e-12
    out = crosses & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps)
    if np.any(planar):
        i = np.flatnonzero(planar)
        out[i] = _planar(p[i], q[i], a[i], b[i], c[i])
    return out


def _planar(p, q, a, b, c):
    """The coplanar case in 2D (the plane's dominant axis dropped)."""
    n = np.cross(b - a, c - a)
    drop = np.argmax(np.abs(n), axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[drop]
    pick = lambda v: np.take_along_axis(v, keep, axis=1)  # noqa: E731
    p, q, a, b, c = map(pick, (p, q, a, b, c))

    def cross2(o, u, v):
        return (u[:, 0] - o[:, 0]) * (v[:, 1] - o[:, 1]) - (u[:, 1] - o[:, 1]) * (v[:, 0] - o[:, 0])

    def inside(x):
        d1, d2, d3 = cross2(a, b, x), cross2(b, c, x), cross2(c, a, x)
        return ((d1 >= 0) & (d2 >= 0) & (d3 >= 0)) | ((d1 <= 0) & (d2 <= 0) & (d3 <= 0))

    def seg(u0, u1, v0, v1):
        d1, d2 = cross2(u0, u1, v0), cross2(u0, u1, v1)
        d3, d4 = cross2(v0, v1, u0), cross2(v0, v1, u1)
        return (d1 * d2 <= 0) & (d3 * d4 <= 0)

    return inside(p) | inside(q) | seg(p, q, a, b) | seg(p, q, b, c) | seg(p, q, c, a)


def crossings(x, faces, edges):
    """``(K, 2)`` every (edge id, face id) pair that meets, without a common vertex."""
    import jax.numpy as jnp

    from .broadphase import overlapping_jit

    x = np.asarray(x, np.float64)
    faces, edges = np.asarray(faces), np.asarray(edges)
    pad = 1e-6 * max(float(np.ptp(x, axis=0).max()), 1e-12)
    lo_e, hi_e = x[edges].min(1) - pad, x[edges].max(1) + pad
    lo_f, hi_f = x[faces].min(1) - pad, x[faces].max(1) + pad
    E, F = jnp.asarray(edges), jnp.asarray(faces)
    cap = 4 * (len(edges) + len(faces))
    while True:
        pr = overlapping_jit(jnp.asarray(lo_e), jnp.asarray(hi_e), jnp.asarray(lo_f), jnp.asarray(hi_f), cap, E, F)
        if not bool(pr.overflow):
            break
        cap *= 4
    on = np.asarray(pr.on)
    ie, jf = np.asarray(pr.a)[on], np.asarray(pr.b)[on]
    if ie.size == 0:
        return np.zeros((0, 2), np.int64)
    tol = 1e-13 * max(float(np.ptp(x, axis=0).max()), 1e-12) ** 3
    p, q = x[edges[ie, 0]], x[edges[ie, 1]]
    a, b, c = x[faces[jf, 0]], x[faces[jf, 1]], x[faces[jf, 2]]
    hit = _segment_triangle(p, q, a, b, c, tol)
    return np.stack([ie[hit], jf[hit]], axis=1)


def first_intersection(x, faces, edges) -> str | None:
    """A description of the first self-intersection of the mesh at ``x (N, 3)``, or ``None``."""
    hits = crossings(x, faces, edges)
    if hits.shape[0] == 0:
        return None
    e, f = hits[0]
    return (f"edge {e} (particles {np.asarray(edges)[e].tolist()}) passes through triangle {f} (particles "
            f"{np.asarray(faces)[f].tolist()}); {hits.shape[0]} such crossings in all")
