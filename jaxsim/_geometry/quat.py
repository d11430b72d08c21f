"""Vectors and unit quaternions as tuples of component arrays.

A vector is a tuple ``(x, y, z)`` and a quaternion a tuple ``(w, x, y, z)`` of arrays of
one batch shape ``B`` (structure of arrays).  Every operation is then plain elementwise
arithmetic on ``B``-shaped arrays, which XLA fuses into one loop per joint update: no
slicing, no small matrix products.  ``stack``/``unstack`` convert to the public storage
(components on an axis).

All functions are NaN-free in value and gradient at zero vectors (the double-``where``
pattern), which keeps degenerate IK poses safe to differentiate.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._dtype import tiny


def unstack(a, axis: int = 0):
    """Array with components on ``axis`` -> tuple of component arrays."""
    a = jnp.moveaxis(a, axis, 0)
    return tuple(a[k] for k in range(a.shape[0]))


def stack(v, axis: int = 0):
    """Tuple of component arrays -> array with components on ``axis``."""
    return jnp.stack(jnp.broadcast_arrays(*v), axis=axis)


def where(c, a, b):
    """Componentwise ``jnp.where`` over tuples (or any matching pytrees)."""
    return jax.tree_util.tree_map(lambda x, y: jnp.where(c, x, y), a, b)


def add(a, b):
    return tuple(x + y for x, y in zip(a, b))


def sub(a, b):
    return tuple(x - y for x, y in zip(a, b))


def scale(s, a):
    return tuple(s * x for x in a)


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dtype(v):
    return jnp.result_type(*v)


def sqnorm(v):
    return sum(x * x for x in v)


def safe_norm(v):
    """Euclidean norm, with a zero (not NaN) gradient at ``v = 0``; NaN stays NaN."""
    return safe_sqrt(sqnorm(v))


def safe_sqrt(s):
    """``sqrt(s)`` of a squared norm, with a zero (not NaN) gradient at ``s = 0``."""
    ok = ~(s <= tiny(s.dtype) ** 2)
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, s, 1.0)), 0.0)


def normalize(v, fallback):
    """``v / |v|``, or the unit vector ``fallback`` where ``|v|`` is too small to divide by."""
    n = safe_norm(v)
    ok = ~(n <= tiny(_dtype(v)))
    inv = 1.0 / jnp.where(ok, n, 1.0)
    return tuple(jnp.where(ok, x * inv, f) for x, f in zip(v, fallback))


def identity(batch_shape=(), dtype=jnp.float32):
    one, zero = jnp.ones(batch_shape, dtype), jnp.zeros(batch_shape, dtype)
    return (one, zero, zero, zero)


def mul(a, b):
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def conj(q):
    """Conjugate, the inverse of a unit quaternion."""
    return (q[0], -q[1], -q[2], -q[3])


def rotate(q, v):
    """Rotate vector ``v`` by unit quaternion ``q``: ``v + w t + u x t`` with ``t = 2 u x v``."""
    u = q[1:]
    t = scale(2.0, cross(u, v))
    return add(add(v, scale(q[0], t)), cross(u, t))


def renormalize(q):
    """Project back onto the unit sphere (removes floating-point drift)."""
    inv = jax.lax.rsqrt(sqnorm(q))
    return scale(inv, q)


def renormalize_near_unit(q):
    """``q (3 - |q|^2) / 2``: one Newton step of ``q / |q|`` for a ``q`` already near unit.

    A norm off by ``δ`` comes out off by about ``1.5 δ^2``: the drift of a product of
    unit quaternions (a few ulps) is removed to rounding, without the ``rsqrt`` that kept
    XLA from fusing :func:`renormalize` into the product before it.  Only for ``|q|^2``
    well inside ``(0, 5)``; use :func:`renormalize` elsewhere.
    """
    return scale(1.5 - 0.5 * sqnorm(q), q)


def unit_quaternions(q):
    """``q / |q|`` over the last axis of a ``(..., 4)`` array; a zero quaternion becomes the
    identity ``(1, 0, 0, 0)``.

    Scaled by the largest component first, so neither huge nor tiny quaternions over- or
    underflow; NaN-free in value and gradient at zero (double ``where``).
    """
    q = jnp.asarray(q)
    big = jnp.max(jnp.abs(q), axis=-1, keepdims=True)
    ok = big > 0
    qs = q / jnp.where(ok, big, 1.0)
    n = jnp.sqrt(jnp.where(ok, jnp.sum(qs * qs, axis=-1, keepdims=True), 1.0))
    ident = jnp.zeros_like(q).at[..., 0].set(1.0)
    return jnp.where(ok, qs / jnp.where(ok, n, 1.0), ident)


def perpendicular(a):
    """A unit vector perpendicular to ``a`` (any unit vector if ``a`` is zero)."""
    ax, ay, az = (jnp.abs(x) for x in a)
    use_x = ax <= 0.57 * (ax + ay + az)
    # a x e_x = (0, az, -ay); a x e_y = (-az, 0, ax)
    zero = jnp.zeros_like(a[0])
    p = (
        jnp.where(use_x, zero, -a[2]),
        jnp.where(use_x, a[2], zero),
        jnp.where(use_x, -a[1], a[0]),
    )
    return normalize(p, (zero, zero, jnp.ones_like(zero)))


def from_two_vectors(a, b):
    """Shortest-arc rotation taking the direction of ``a`` to that of ``b``.

    Uses ``q ∝ (|a||b| + a·b, a × b)``, accurate for tiny angles (no ``acos`` and no
    small-angle cut-off).  Returns the identity if either vector is zero, and a half-turn
    about an axis perpendicular to ``a`` if they are opposite.
    """
    scale_ab = safe_norm(a) * safe_norm(b)
    w = scale_ab + dot(a, b)
    q = (w, *cross(a, b))
    nq = safe_norm(q)
    dt = _dtype(a)
    zero_input = scale_ab <= tiny(dt)
    opposite = (~zero_input) & (nq <= 1e-6 * scale_ab)
    good = ~(zero_input | opposite)
    inv = 1.0 / jnp.where(good, nq, 1.0)
    p = perpendicular(a)
    zero = jnp.zeros_like(w)
    half_turn = (zero, *p)
    ident = (jnp.ones_like(w), zero, zero, zero)
    return where(good, scale(inv, q), where(opposite, half_turn, ident))


def arc_lean(a, b, half_turn_axis=None):
    """Shortest-arc rotation from the direction of ``a`` to that of ``b``, for batched code.

    The half-way form ``q ∝ (|h|^2 / 2, â × b̂)`` with ``h = â + b̂`` (so ``q_w = 1 + â·b̂``
    without the cancellation of ``1 + cos θ`` next to a half-turn), in three ``rsqrt``.
    Each squared norm is offset by ``e^2`` and ``q_w`` by ``e``, with ``e`` about
    ``16 / cbrt(finfo.max)`` (2e-12 in float32, 1e-101 in float64): a zero ``a`` or ``b``
    gives the identity, never NaN, and ``rsqrt``'s derivative ``x^(-3/2)`` stays finite,
    so gradients are NaN-free.

    Vectors opposite to within ``4 eps`` rad give the half-turn about
    ``half_turn_axis`` (a unit vector perpendicular to ``a``) when it is given, and the
    identity (no turn) when it is ``None``: then there is no select at all.
    :func:`from_two_vectors` costs two ``sqrt``, a divide, a perpendicular per element
    and two selects, which in batched sweeps kept XLA from fusing the arc with its
    neighbours (``benchmarks/ik_throughput.py``).
    """
    dt = _dtype(a)
    e = 16.0 * float(jnp.finfo(dt).max) ** (-1.0 / 3.0)
    sa, sb = sqnorm(a), sqnorm(b)
    ua = scale(jax.lax.rsqrt(sa + e * e), a)
    ub = scale(jax.lax.rsqrt(sb + e * e), b)
    w = 0.5 * sqnorm(add(ua, ub))
    c = cross(ua, ub)
    n2 = (w + e) * (w + e) + sqnorm(c)
    inv = jax.lax.rsqrt(n2)
    q = ((w + e) * inv, *scale(inv, c))
    if half_turn_axis is None:
        return q
    # |q|^2 = 2 (1 + cos θ) before the offsets: below 16 eps^2 the pair is opposite to 4 eps rad
    opposite = (n2 <= 16.0 * float(jnp.finfo(dt).eps) ** 2) & (sa > e * e) & (sb > e * e)
    zero = jnp.zeros_like(w)
    return where(opposite, (zero, *(x + zero for x in half_turn_axis)), q)


def angle(q):
    """Rotation angle in radians, in ``[0, pi]``."""
    return 2.0 * jnp.arctan2(safe_norm(q[1:]), jnp.abs(q[0]))


def clamp_angle(q, max_angle):
    """Scale rotation ``q`` down so its angle is at most ``max_angle`` (same axis, short way)."""
    q = where(q[0] < 0, scale(-1.0, q), q)
    ang = angle(q)
    axis = normalize(q[1:], perpendicular(q[1:]))
    half = 0.5 * jnp.minimum(ang, max_angle)
    limited = (jnp.cos(half), *scale(jnp.sin(half), axis))
    return where(ang > max_angle, limited, q)


def slerp(a, b, t):
    """Spherical linear interpolation from unit ``a`` (``t = 0``) to unit ``b`` (``t = 1``),
    the short way (Shoemake 1985).  The angle is ``2 atan2(|a - b|, |a + b|)``, accurate at
    every size, and near zero the weights ``(1 - t, t)`` and a renormalisation take over
    (NaN-free in value and gradient)."""
    b = where(dot(a[1:], b[1:]) + a[0] * b[0] < 0, scale(-1.0, b), b)
    phi = 2.0 * jnp.arctan2(safe_norm(sub(a, b)), safe_norm(add(a, b)))
    small = phi < 1e-4
    s = jnp.sin(jnp.where(small, 1.0, phi))
    wa = jnp.where(small, 1.0 - t, jnp.sin((1.0 - t) * jnp.where(small, 1.0, phi)) / s)
    wb = jnp.where(small, t, jnp.sin(t * jnp.where(small, 1.0, phi)) / s)
    out = add(scale(wa, a), scale(wb, b))
    return where(small, renormalize(out), out)
