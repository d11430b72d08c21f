"""Joint limits (Aristidou & Lasenby 2011, §4.1): the specs and their solver data.

A limit constrains a joint's local rotation ``L``: :class:`Hinge` (a rotation about an axis
by an angle in ``[lo, hi]``), :class:`SwingTwist` (``L = S T``: a twist about the bone's
axis in a range, and a swing of at most a cone angle), :class:`Fixed` (the identity), or
:class:`Free`/``None``.  Angles are radians.  Specs are frozen and hashable (the solvers
compile per pattern of kinds); the numbers travel as data (:class:`LimitTable`).
Their projection and violation are in ``projection``.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..._dataclass import pytree_dataclass, static_field
from ..._validate import check_real
from ..._geometry import quat as _quat


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
