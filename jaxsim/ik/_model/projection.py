"""Angles about an axis, and the projection of rotations onto joint limit sets (``limits``).

:func:`clamp` moves a rotation into its limit set, twist and swing clamped separately:
the result is always in the set (the nearest point for a hinge, or where only one part
is violated).  Every solver uses it: per joint (:func:`project`) in the sweeps, over
stacked joints (``stacked.apply_bounds``) at a solve's start and end, in LM, and in
:func:`project_limits`.
"""

from __future__ import annotations

import jax.numpy as jnp

from ..._geometry import quat as _quat
from .limits import JointLimit


def _canonical(q):
    return _quat.where(q[0] < 0, _quat.scale(-1.0, q), q)


def _twist(q, a):
    """The twist of ``q`` (``w >= 0``) about unit axis ``a``: ``q = swing * twist``; identity when undefined."""
    q = _canonical(q)
    p = _quat.dot(q[1:], a)
    t = (q[0], *_quat.scale(p, a))
    one, zero = jnp.ones_like(q[0]), jnp.zeros_like(q[0])
    return q, _quat.normalize(t, (one, zero, zero, zero))


def _twist_angle(t, a):
    """Signed angle of the twist ``t`` (``w >= 0``) about ``a``, in ``[-pi, pi]``."""
    return 2.0 * jnp.arctan2(_quat.dot(t[1:], a), t[0])


def _wrap(x):
    return jnp.mod(x + jnp.pi, 2 * jnp.pi) - jnp.pi


def _outside(theta, lo, hi):
    """How far (rad, around the circle) ``theta`` lies outside ``[lo, hi]``; 0 inside."""
    inside = (theta >= lo) & (theta <= hi)
    return jnp.where(inside, 0.0, jnp.minimum(jnp.abs(_wrap(lo - theta)), jnp.abs(_wrap(theta - hi))))


def clamp_range(theta, lo, hi):
    """``theta`` clamped into ``[lo, hi]`` around the circle (to the nearer end)."""
    inside = (theta >= lo) & (theta <= hi)
    to_lo = jnp.abs(_wrap(lo - theta)) <= jnp.abs(_wrap(theta - hi))
    return jnp.where(inside, theta, jnp.where(to_lo, lo, hi))


def about(theta, a):
    """Rotation by ``theta`` about the unit axis ``a`` (component tuples)."""
    half = 0.5 * theta
    return (jnp.cos(half), *_quat.scale(jnp.sin(half), a))


def safe_atan2(y, x):
    """``atan2(y, x)``, 0 (with zero gradient) where both vanish."""
    ok = ~(y * y + x * x <= jnp.finfo(jnp.result_type(x)).tiny)
    return jnp.where(ok, jnp.arctan2(jnp.where(ok, y, 0.0), jnp.where(ok, x, 1.0)), 0.0)


def hinge_angle(q, a):
    """The angle (rad, ``[-pi, pi]``) of ``q``'s twist about the unit axis ``a``."""
    return _twist_angle(_twist(q, a)[1], a)


def best_angle(n, a, b, w):
    """The angle about the unit axis ``n`` turning the vectors ``a_k`` closest to ``b_k``:
    ``argmax_t sum_k w_k b_k . R_n(t) a_k`` in closed form (0 when every pair is degenerate)."""
    s = sum(wk * _quat.dot(n, _quat.cross(ak, bk)) for ak, bk, wk in zip(a, b, w))
    c = sum(wk * (_quat.dot(ak, bk) - _quat.dot(n, ak) * _quat.dot(n, bk)) for ak, bk, wk in zip(a, b, w))
    return safe_atan2(s, c)


def twist_end(x, a):
    """The twist by ``x`` (rad) about the unit axis ``a``, ``(cos(x/2), sin(x/2) a)``: a range end."""
    return about(x, a)


def clamp(q, a, lo, hi, cone, hinge, swing, fixed):
    """``q`` (unit quaternion tuple) moved into a hinge, swing-twist or fixed limit set.

    Args:
      a: unit twist or hinge axis (vector tuple); lo, hi: the twists at the range ends
        (:func:`twist_end`); cone: ``(cos, sin)`` of half the cone angle.
      hinge, swing, fixed: the kind, as Python bools or boolean arrays over the last
        axis (one joint per element, ``stacked``); a joint of no kind is free.

    With ``q`` canonical (``w >= 0``), its twist ``t`` about ``a`` has a half angle
    ``theta/2`` in ``[-pi/2, pi/2]``, so ``theta >= lo`` iff ``sin((theta - lo)/2) >= 0``,
    a product of the twist's and the end's components, and the nearer end around the
    circle is the one with the larger ``|t . t_end|``.  The swing ``s`` (``w >= 0``) is
    outside the cone iff ``|s_v| cos(cone/2) - s_w sin(cone/2) > 0``.  The twist and the
    swing are clamped apart; no inverse trigonometry.  Sines of the differences, not
    comparisons of cosines, which are flat near zero: a 20-degree cone tested by
    ``s_w < cos(10 deg)`` let float32 swings through by up to 9.5e-7 rad.
    """
    def pick(mask, x, y):
        return x if mask is True else y if mask is False else _quat.where(mask, x, y)

    qc, t = _twist(q, a)
    s = _quat.dot(t[1:], a)  # sin(theta / 2), and t[0] = cos(theta / 2)
    inside = (s * lo[0] - t[0] * _quat.dot(lo[1:], a) >= 0) & (_quat.dot(hi[1:], a) * t[0] - hi[0] * s >= 0)
    to_lo = jnp.abs(t[0] * lo[0] + _quat.dot(t[1:], lo[1:])) >= jnp.abs(t[0] * hi[0] + _quat.dot(t[1:], hi[1:]))
    tw = _quat.where(inside, t, _quat.where(to_lo, lo, hi))
    out = pick(hinge, tw, q)
    if swing is not False:
        sw = _quat.mul(qc, _quat.conj(t))
        sw = _quat.where(sw[0] < 0, _quat.scale(-1.0, sw), sw)
        cos_h, sin_h = cone
        rim = (cos_h + jnp.zeros_like(sw[0]), *_quat.scale(sin_h, _quat.normalize(sw[1:], _quat.perpendicular(sw[1:]))))
        sw = _quat.where(_quat.safe_norm(sw[1:]) * cos_h - sw[0] * sin_h > 0, rim, sw)
        out = pick(swing, _quat.renormalize(_quat.mul(sw, tw)), out)
    if fixed is not False:
        one, zero = jnp.ones_like(q[0]), jnp.zeros_like(q[0])
        out = pick(fixed, (one, zero, zero, zero), out)
    return out


def project(q, lim: JointLimit):
    """``q`` (a unit quaternion tuple, any batch shape) moved into one joint's limit set (:func:`clamp`)."""
    kind, a = lim.kind, lim.axis
    if kind == "free":
        return q
    if kind == "fixed":
        one, zero = jnp.ones_like(q[0]), jnp.zeros_like(q[0])
        return (one, zero, zero, zero)
    half = 0.5 * lim.swing
    return clamp(q, a, twist_end(lim.lo, a), twist_end(lim.hi, a), (jnp.cos(half), jnp.sin(half)), kind == "hinge",
                 kind == "swing", False)


def violation(q, lim: JointLimit):
    """Radians by which ``q`` lies outside one joint's limit set (0 inside)."""
    kind, a, lo, hi, swing = lim.kind, lim.axis, lim.lo, lim.hi, lim.swing
    if kind == "free":
        return jnp.zeros_like(q[0])
    if kind == "fixed":
        return _quat.angle(q)
    q, t = _twist(q, a)
    off = _quat.angle(_quat.mul(q, _quat.conj(t)))
    tw = _outside(_twist_angle(t, a), lo, hi)
    return tw + (off if kind == "hinge" else jnp.maximum(off - swing, 0.0))
