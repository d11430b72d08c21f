"""Joint limits (Aristidou & Lasenby 2011, §4.1): specs, their projection and violation.

A limit constrains a joint's local rotation ``L``: :class:`Hinge` (a rotation about an axis
by an angle in ``[lo, hi]``), :class:`SwingTwist` (``L = S T``: a twist about the bone's
axis in a range, and a swing of at most a cone angle), :class:`Fixed` (the identity), or
:class:`Free`/``None``.  Angles are radians.  Specs are frozen and hashable (the solvers
compile per pattern of kinds); the numbers travel as data (:class:`LimitTable`).
:func:`project` clamps twist and swing separately: the result is always in the set (the
nearest point for a hinge, or where only one part is violated).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._dataclass import pytree_dataclass, static_field
from .._validate import check_real
from .._geometry import quat as _quat


def _unit_axis(name, axis):
    a = np.asarray(axis, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} axis must be 3 finite numbers, got {axis!r}")
    n = float(np.linalg.norm(a))
    if n <= 1e-12:
        raise ValueError(f"{name} axis must be non-zero, got {axis!r}")
    return tuple(float(x) for x in a / n)


def _range(name, lo, hi):
    lo, hi = check_real(f"{name} lo", lo), check_real(f"{name} hi", hi)
    if lo > hi:
        raise ValueError(f"{name}: lo > hi ({lo!r} > {hi!r})")
    if lo < -math.pi - 1e-9 or hi > math.pi + 1e-9:
        raise ValueError(f"{name}: the range [{lo!r}, {hi!r}] must lie within [-pi, pi]")
    return lo, hi


@dataclasses.dataclass(frozen=True)
class Free:
    """No limit (the default)."""


@dataclasses.dataclass(frozen=True)
class Fixed:
    """The joint keeps the identity local rotation."""


@dataclasses.dataclass(frozen=True)
class Hinge:
    """A rotation about ``axis`` (parent frame; normalised) by an angle in ``[lo, hi]`` (rad).

    Raises:
      ValueError: a zero or non-finite axis, ``lo > hi``, or a range outside ``[-pi, pi]``.
    """

    axis: tuple
    lo: float
    hi: float

    def __post_init__(self):
        object.__setattr__(self, "axis", _unit_axis("Hinge", self.axis))
        lo, hi = _range("Hinge", self.lo, self.hi)
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)


@dataclasses.dataclass(frozen=True)
class SwingTwist:
    """The bone within a cone of half-angle ``swing`` about ``axis``, twisted by an angle in ``twist``.

    Attributes:
      swing: the cone's half-angle, in ``[0, pi]`` (rad).
      twist: ``(lo, hi)`` twist range about ``axis`` (rad), within ``[-pi, pi]``.
      axis: the twist axis in the joint's rest frame (normalised); ``None`` = the rest
        direction of the joint's bone (its first child's offset; a leaf's own offset).

    Raises:
      ValueError: a negative or non-finite cone angle, ``lo > hi``, or a zero axis.
    """

    swing: float
    twist: tuple = (-math.pi, math.pi)
    axis: tuple | None = None

    def __post_init__(self):
        s = check_real("SwingTwist swing", self.swing)
        if s < 0:
            raise ValueError(f"SwingTwist swing (the cone angle) must be >= 0, got {self.swing!r}")
        if s > math.pi + 1e-9:
            raise ValueError(f"SwingTwist swing must be <= pi, got {self.swing!r}")
        object.__setattr__(self, "swing", s)
        try:
            lo, hi = self.twist
        except (TypeError, ValueError):
            raise ValueError(f"SwingTwist twist must be a (lo, hi) pair, got {self.twist!r}") from None
        object.__setattr__(self, "twist", _range("SwingTwist twist", lo, hi))
        if self.axis is not None:
            object.__setattr__(self, "axis", _unit_axis("SwingTwist", self.axis))


_KIND = {Free: "free", Fixed: "fixed", Hinge: "hinge", SwingTwist: "swing"}


def check_limits(limits, parents) -> tuple | None:
    """A skeleton's ``limits``: ``None``, or one spec (or ``None``) per joint."""
    if limits is None:
        return None
    try:
        limits = tuple(limits)
    except TypeError:
        raise ValueError(f"limits must be a sequence of one limit (or None) per joint, got {limits!r}") from None
    if len(limits) != len(parents):
        raise ValueError(f"limits has {len(limits)} entries for {len(parents)} joints")
    out = []
    for i, lim in enumerate(limits):
        lim = Free() if lim is None else lim
        if type(lim) not in _KIND:
            raise ValueError(f"limits[{i}] must be Free, Fixed, Hinge, SwingTwist or None, got {lim!r}")
        out.append(lim)
    return None if all(isinstance(x, Free) for x in out) else tuple(out)


@pytree_dataclass
class LimitTable:
    """A skeleton's limits as solver data.

    Attributes:
      kinds: static tuple of ``J`` kinds, ``"free" | "fixed" | "hinge" | "swing"``.
      axis: ``(J, 3)`` unit hinge or twist axes.
      lo, hi: ``(J,)`` hinge or twist range (rad).
      swing: ``(J,)`` cone half-angles (rad).
    """

    kinds: tuple = static_field()
    axis: jax.Array
    lo: jax.Array
    hi: jax.Array
    swing: jax.Array

    def joint(self, i) -> JointLimit:
        """Joint ``i``'s limit."""
        return JointLimit(self.kinds[i], _quat.unstack(self.axis[i]), self.lo[i], self.hi[i], self.swing[i])


@dataclasses.dataclass(frozen=True)
class JointLimit:
    """One joint's limit as solver data (a row of :class:`LimitTable`).

    Attributes:
      kind: ``"free" | "fixed" | "hinge" | "swing"``.
      axis: unit hinge or twist axis, a vector tuple (parent frame).
      lo, hi: ``()`` hinge or twist range (rad).
      swing: ``()`` cone half-angle (rad).
    """

    kind: str
    axis: tuple
    lo: object
    hi: object
    swing: object


def limit_table(skeleton) -> LimitTable | None:
    """The skeleton's :class:`LimitTable`, or ``None`` when every joint is free."""
    if skeleton.limits is None:
        return None
    offsets, kids = skeleton.offsets, skeleton.children
    dtype = offsets.dtype
    axis, lo, hi, swing = [], [], [], []
    for i, lim in enumerate(skeleton.limits):
        a, l, h, s = (1.0, 0.0, 0.0), -math.pi, math.pi, math.pi
        if isinstance(lim, Hinge):
            a, l, h = lim.axis, lim.lo, lim.hi
        elif isinstance(lim, SwingTwist):
            (l, h), s = lim.twist, lim.swing
            if lim.axis is None:
                bone = offsets[kids[i][0]] if kids[i] else offsets[i]
                a = bone / jnp.sqrt(jnp.sum(bone * bone))
            else:
                a = lim.axis
        axis.append(jnp.asarray(a, dtype))
        lo.append(l)
        hi.append(h)
        swing.append(s)
    return LimitTable(kinds=tuple(_KIND[type(x)] for x in skeleton.limits), axis=jnp.stack(axis),
                      lo=jnp.asarray(lo, dtype), hi=jnp.asarray(hi, dtype), swing=jnp.asarray(swing, dtype))


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


def _safe_atan2(y, x):
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
    return _safe_atan2(s, c)


def project(q, lim: JointLimit):
    """``q`` (a unit quaternion tuple, any batch shape) moved into one joint's limit set."""
    kind, a, lo, hi, swing = lim.kind, lim.axis, lim.lo, lim.hi, lim.swing
    if kind == "free":
        return q
    if kind == "fixed":
        one, zero = jnp.ones_like(q[0]), jnp.zeros_like(q[0])
        return (one, zero, zero, zero)
    q, t = _twist(q, a)
    twist = about(clamp_range(_twist_angle(t, a), lo, hi), a)
    if kind == "hinge":
        return twist
    s = _quat.clamp_angle(_quat.mul(q, _quat.conj(t)), swing)
    return _quat.renormalize(_quat.mul(s, twist))


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


def project_all(table: LimitTable | None, L, joints=None):
    """Project each joint's rotation in the list ``L`` (``None`` entries skipped)."""
    if table is None:
        return list(L)
    joints = range(len(L)) if joints is None else joints
    out = list(L)
    for i in joints:
        if out[i] is not None and table.kinds[i] != "free":
            out[i] = project(out[i], table.joint(i))
    return out


def _joint_rotations(skeleton, rotations):
    """``rotations (..., J, 4)`` checked and normalised: ``(bad (..., J), list of J tuples)``,
    ``bad`` marking rotations with a NaN or inf entry."""
    raw = jnp.asarray(rotations, skeleton.offsets.dtype)
    J = skeleton.num_joints
    if raw.shape[-2:] != (J, 4):
        raise ValueError(f"rotations must have shape (..., {J}, 4), got {raw.shape}")
    q = _quat.unit_quaternions(raw)
    return ~jnp.all(jnp.isfinite(raw), axis=-1), [_quat.unstack(q[..., i, :], axis=-1) for i in range(J)]


def limit_violation(skeleton, rotations) -> jax.Array:
    """Per joint, the angle (rad) by which ``rotations (..., J, 4)`` break the skeleton's limits.

    Returns:
      ``(..., J)``: 0 for a joint within its limit (and for a free joint); ``inf`` for a
      rotation with a NaN or inf entry, which is within no limit.
    """
    bad, L = _joint_rotations(skeleton, rotations)
    table = limit_table(skeleton)
    if table is None:
        v = jnp.zeros(bad.shape, L[0][0].dtype)
    else:
        v = jnp.stack([violation(q, table.joint(i)) for i, q in enumerate(L)], axis=-1)
    return jnp.where(bad, jnp.inf, v)


def project_limits(skeleton, rotations) -> jax.Array:
    """``rotations (..., J, 4)`` moved into the skeleton's limits, joint by joint (normalised first).

    A rotation already within its limit is returned unchanged (up to rounding); one with
    a NaN or inf entry comes back as NaN (it has no nearest rotation in the limit).
    """
    bad, L = _joint_rotations(skeleton, rotations)
    L = project_all(limit_table(skeleton), L)
    return jnp.where(bad[..., None], jnp.nan, jnp.stack([_quat.stack(q, axis=-1) for q in L], axis=-2))
