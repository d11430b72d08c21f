"""Unit quaternions in (w, x, y, z) order, stored component-first.

Every function here takes quaternions of shape ``(4, *batch)`` and vectors of shape
``(3, *batch)``: the component axis is axis 0, so a batch of any shape trails and
broadcasts.  The public IK API stores rotations as ``(J, 4)``; the solvers move the
component axis to the front once, at their boundary.

All functions are NaN-free in value and gradient at zero vectors (the "double ``where``"
pattern), which keeps degenerate IK poses safe to differentiate.
"""

from __future__ import annotations

import jax.numpy as jnp

from .._dtype import tiny


def dot(a, b):
    """Dot product over the component axis. ``(3, *B), (3, *B) -> (*B)``."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    """Cross product over the component axis. ``(3, *B), (3, *B) -> (3, *B)``."""
    return jnp.stack(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def safe_norm(v):
    """Euclidean norm over axis 0, with a zero (not NaN) gradient at ``v = 0``."""
    s = jnp.sum(v * v, axis=0)
    ok = s > tiny(v.dtype) ** 2
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, s, 1.0)), 0.0)


def normalize(v, fallback):
    """``v / |v|``, or ``fallback`` (already unit) where ``|v|`` is too small to divide by."""
    n = safe_norm(v)
    ok = n > tiny(v.dtype)
    return jnp.where(ok, v / jnp.where(ok, n, 1.0), fallback)


def identity(batch_shape=(), dtype=jnp.float32):
    """Identity quaternions of shape ``(4, *batch_shape)``."""
    q = jnp.zeros((4, *batch_shape), dtype)
    return q.at[0].set(1.0)


def mul(a, b):
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``)."""
    aw, ax, ay, az = a[0], a[1], a[2], a[3]
    bw, bx, by, bz = b[0], b[1], b[2], b[3]
    return jnp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def conj(q):
    """Conjugate, the inverse of a unit quaternion."""
    return jnp.concatenate([q[:1], -q[1:]], axis=0)


def rotate(q, v):
    """Rotate vector(s) ``v (3, *B)`` by unit quaternion(s) ``q (4, *B)``."""
    u = q[1:]
    t = 2.0 * cross(u, v)
    return v + q[0] * t + cross(u, t)


def renormalize(q, axis: int = 0):
    """Project back onto the unit sphere along ``axis`` (removes floating-point drift)."""
    return q / jnp.sqrt(jnp.sum(q * q, axis=axis, keepdims=True))


def perpendicular(a):
    """A unit vector perpendicular to ``a (3, *B)`` (any, if ``a`` is zero)."""
    ax = jnp.abs(a[0])
    use_x = ax <= 0.57 * (jnp.abs(a[0]) + jnp.abs(a[1]) + jnp.abs(a[2]))
    e = jnp.stack([jnp.where(use_x, 1.0, 0.0), jnp.where(use_x, 0.0, 1.0), jnp.zeros_like(ax)])
    e = e.astype(a.dtype)
    p = cross(a, e)
    fallback = jnp.stack([jnp.zeros_like(ax), jnp.zeros_like(ax), jnp.ones_like(ax)]).astype(a.dtype)
    return normalize(p, fallback)


def from_two_vectors(a, b):
    """Shortest-arc rotation taking the direction of ``a`` to that of ``b``.

    Uses ``q ∝ (|a||b| + a·b, a × b)``, which stays accurate for tiny angles (no
    ``acos`` and no small-angle cut-off).  Returns the identity if either vector is
    zero, and a half-turn about an axis perpendicular to ``a`` if they are opposite.

    Args:
      a, b: ``(3, *B)`` vectors, not necessarily unit.

    Returns:
      ``(4, *B)`` unit quaternions.
    """
    na, nb = safe_norm(a), safe_norm(b)
    w = na * nb + dot(a, b)
    xyz = cross(a, b)
    q = jnp.concatenate([w[None], xyz], axis=0)
    nq = safe_norm(q)
    scale = na * nb
    small = tiny(a.dtype)
    zero_input = scale <= small
    # Opposite vectors: w and |a x b| both vanish relative to |a||b|.
    opposite = (~zero_input) & (nq <= 1e-6 * jnp.where(zero_input, 1.0, scale))
    good = ~(zero_input | opposite)
    q_unit = q / jnp.where(good, nq, 1.0)
    half_turn = jnp.concatenate([jnp.zeros_like(w)[None], perpendicular(a)], axis=0)
    ident = identity(w.shape, a.dtype)
    return jnp.where(good, q_unit, jnp.where(opposite, half_turn, ident))


def angle(q):
    """Rotation angle in radians, in [0, pi], of unit quaternion(s) ``q (4, *B)``."""
    s = safe_norm(q[1:])
    return 2.0 * jnp.arctan2(s, jnp.abs(q[0]))


def clamp_angle(q, max_angle):
    """Scale the rotation ``q`` down so its angle is at most ``max_angle`` (same axis).

    Takes the short way round (``q`` and ``-q`` are the same rotation).
    """
    q = jnp.where(q[0] < 0, -q, q)
    ang = angle(q)
    axis = normalize(q[1:], perpendicular(q[1:]))
    limited = ang > max_angle
    half = 0.5 * jnp.minimum(ang, max_angle)
    q_lim = jnp.concatenate([jnp.cos(half)[None], jnp.sin(half) * axis], axis=0)
    return jnp.where(limited, q_lim, q)


def to_last(q):
    """``(4, *B) -> (*B, 4)``: component axis last, the public storage order."""
    return jnp.moveaxis(q, 0, -1)


def to_first(q):
    """``(*B, 4) -> (4, *B)``."""
    return jnp.moveaxis(q, -1, 0)
