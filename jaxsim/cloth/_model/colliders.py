"""Static or kinematic colliders: a plane, a sphere and a capsule (small pytrees).

Each collider gives, for particle positions ``x (..., 3)``:

- ``distance(x) (...)``: the signed distance to its surface (m), positive outside;
- ``distance_from(x0, u) (...)``: the same at ``x0 + u``, with the change computed from
  ``u`` without cancellation (float32 resolves contact gaps far below ``eps |x|``);
- ``normal_at(x) (..., 3)``: the unit gradient of ``distance``;
- ``time_of_impact(x, dx) (...)``: the first ``t >= 0`` at which ``x + t dx`` touches
  the surface, ``inf`` when it never does (closed form, used to cap Newton's line
  search so that no particle ever crosses a surface; IPC, Li et al. 2020, §4);
- ``push_out(x, gap) (..., 3)``: ``x`` moved to distance ``gap`` where it lies inside;
- ``surface_motion(prev, x) (..., 3)``: how far the surface point next to ``x`` moved
  from ``prev`` to this collider (for friction against a moving collider).

Their parameters are data (differentiable, and a per-step path in ``rollout`` moves
them); ``frictional`` is static: a collider built with ``friction=0`` compiles no
friction term.
"""

from __future__ import annotations

from decimal import Decimal
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np

from ..._dataclass import is_concrete, pytree_dataclass, static_field
from ..._dtype import tiny
from ..._validate import check_finite, check_positive
from .._vec import dot as _dot
from .._vec import length, stretch_increment


def _unit(v, fallback=(0.0, 1.0, 0.0)):
    """``v / |v|`` over the last axis; ``fallback`` where ``v`` is zero (NaN-free gradient)."""
    s = _dot(v, v)
    ok = (s > tiny(v.dtype) ** 2)[..., None]
    n = jnp.sqrt(jnp.where(ok, s[..., None], 1.0))
    return jnp.where(ok, v / n, jnp.asarray(fallback, v.dtype))


def _sphere_toi(p, dx, r):
    """First ``t >= 0`` with ``|p + t dx| = r`` for ``|p| > r``; ``inf`` if none.

    The root ``t = 2c / (-b + sqrt(b^2 - 4ac))`` of ``a t^2 + b t + c`` (no cancellation)."""
    a = _dot(dx, dx)
    b = 2.0 * _dot(p, dx)
    pn = length(p)
    c = (pn - r) * (pn + r)
    disc = b * b - 4.0 * a * c
    hit = (b < 0) & (disc >= 0)
    den = -b + jnp.sqrt(jnp.where(hit, disc, 1.0))
    t = jnp.where(hit, 2.0 * c / jnp.where(hit, den, 1.0), jnp.inf)
    return jnp.where(hit, jnp.maximum(t, 0.0), jnp.inf)


def _given(*values) -> bool:
    """True when the values are a user's (to validate), False when JAX rebuilds the node
    with tracers or placeholder objects (``register_dataclass`` goes through ``__init__``).

    Strings, ``None``, fractions and decimals count as given, so that they are rejected
    rather than switching the checks off."""
    user = (np.ndarray, np.generic, jax.Array, list, tuple, int, float, complex, str, bytes, Fraction, Decimal)
    return all(v is None or (isinstance(v, user) and not isinstance(v, jax.core.Tracer)) for v in values)


def _check(name, value, tail):
    """``value`` as a finite float64 array whose trailing shape is ``tail``; leading axes
    are allowed (a per-step path for ``rollout``)."""
    a = np.asarray(value) if not isinstance(value, (str, bytes)) else np.asarray(value, object)
    if a.dtype == np.bool_ or not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise ValueError(f"{name} must be a real number or array of them, got {value!r:.80} "
                         f"({type(value).__name__}, dtype {a.dtype})")
    a = a.astype(np.result_type(a.dtype, np.float32))
    if a.ndim < len(tail) or a.shape[a.ndim - len(tail):] != tail:
        raise ValueError(f"{name} must have shape {tail} (or one per step, (T,) + {tail}), got {a.shape}")
    return check_finite(name, a)


def _friction(obj):
    mu = _check(f"{type(obj).__name__} friction", obj.friction, ())
    check_positive(f"{type(obj).__name__} friction", mu, strict=False)
    object.__setattr__(obj, "friction", mu)
    return bool(np.any(mu != 0.0))


@pytree_dataclass
class Plane:
    """The half-space ``normal . x >= offset`` is outside.

    Attributes:
      normal: ``(3,)`` outward normal (normalised at construction; ``offset`` is
        divided by its length, so the plane is the one given).
      offset: ``()`` (m).
      friction: ``()`` Coulomb coefficient ``mu >= 0``.
    """

    normal: jax.Array
    offset: jax.Array
    friction: jax.Array = 0.0
    frictional: bool = static_field(default=True)

    def __post_init__(self):
        if not _given(self.normal, self.offset, self.friction):
            return
        n = _check("Plane normal", self.normal, (3,))
        length = np.linalg.norm(n, axis=-1)
        if not np.all(length > 0):
            raise ValueError("Plane normal must be a non-zero vector")
        o = _check("Plane offset", self.offset, ())
        object.__setattr__(self, "normal", n / length[..., None])
        object.__setattr__(self, "offset", o / length)
        object.__setattr__(self, "frictional", bool(self.frictional) and _friction(self))

    def distance(self, x):
        return _dot(x, self.normal) - self.offset

    def distance_from(self, x0, u):
        return self.distance(x0) + _dot(u, self.normal)

    def normal_at(self, x):
        return jnp.broadcast_to(self.normal, x.shape)

    def time_of_impact(self, x, dx):
        rate = _dot(dx, self.normal)
        d = self.distance(x)
        approach = rate < 0
        return jnp.where(approach, jnp.maximum(d, 0.0) / jnp.where(approach, -rate, 1.0), jnp.inf)

    def push_out(self, x, gap):
        d = self.distance(x)[..., None]
        return jnp.where(d < gap, x + (gap - d) * self.normal, x)

    def surface_motion(self, prev: "Plane", x):
        return jnp.broadcast_to((self.offset - prev.offset) * self.normal, x.shape)


@pytree_dataclass
class Sphere:
    """A solid ball.

    Attributes:
      center: ``(3,)`` (m).
      radius: ``()`` (m), > 0.
      friction: ``()`` Coulomb coefficient ``mu >= 0``.
    """

    center: jax.Array
    radius: jax.Array
    friction: jax.Array = 0.0
    frictional: bool = static_field(default=True)

    def __post_init__(self):
        if not _given(self.center, self.radius, self.friction):
            return
        object.__setattr__(self, "center", _check("Sphere center", self.center, (3,)))
        object.__setattr__(self, "radius", check_positive("Sphere radius", _check("Sphere radius", self.radius, ())))
        object.__setattr__(self, "frictional", bool(self.frictional) and _friction(self))

    def distance(self, x):
        return length(x - self.center) - self.radius

    def distance_from(self, x0, u):
        p0 = x0 - self.center
        l0 = length(p0)
        return (l0 - self.radius) + stretch_increment(p0, l0, u)

    def normal_at(self, x):
        return _unit(x - self.center)

    def time_of_impact(self, x, dx):
        return _sphere_toi(x - self.center, dx, self.radius)

    def push_out(self, x, gap):
        d = self.distance(x)[..., None]
        return jnp.where(d < gap, self.center + (self.radius + gap) * self.normal_at(x), x)

    def surface_motion(self, prev: "Sphere", x):
        return jnp.broadcast_to(self.center - prev.center, x.shape)


@pytree_dataclass
class Capsule:
    """The points within ``radius`` of the segment ``a``–``b`` (a ball when ``a == b``).

    Attributes:
      a, b: ``(3,)`` segment ends (m).
      radius: ``()`` (m), > 0.
      friction: ``()`` Coulomb coefficient ``mu >= 0``.
    """

    a: jax.Array
    b: jax.Array
    radius: jax.Array
    friction: jax.Array = 0.0
    frictional: bool = static_field(default=True)

    def __post_init__(self):
        if not _given(self.a, self.b, self.radius, self.friction):
            return
        object.__setattr__(self, "a", _check("Capsule a", self.a, (3,)))
        object.__setattr__(self, "b", _check("Capsule b", self.b, (3,)))
        object.__setattr__(self, "radius", check_positive("Capsule radius", _check("Capsule radius", self.radius, ())))
        object.__setattr__(self, "frictional", bool(self.frictional) and _friction(self))

    def _axis(self):
        ab = self.b - self.a
        return _unit(ab, (0.0, 0.0, 0.0)), length(ab)

    def _param(self, x):
        """Arc length ``t`` of the closest segment point, in ``[0, |b - a|]``."""
        w, length = self._axis()
        return jnp.clip(_dot(x - self.a, w), 0.0, length), w

    def closest(self, x):
        t, w = self._param(x)
        return self.a + t[..., None] * w

    def distance(self, x):
        return length(x - self.closest(x)) - self.radius

    def distance_from(self, x0, u):
        w, span = self._axis()
        s0 = _dot(x0 - self.a, w)
        t0 = jnp.clip(s0, 0.0, span)
        p0 = x0 - (self.a + t0[..., None] * w)
        l0 = length(p0)
        dt = jnp.clip(s0 + _dot(u, w), 0.0, span) - t0
        return (l0 - self.radius) + stretch_increment(p0, l0, u - dt[..., None] * w)

    def normal_at(self, x):
        return _unit(x - self.closest(x))

    def time_of_impact(self, x, dx):
        """The first hit of the union of the infinite cylinder's finite part and the end balls."""
        w, length = self._axis()
        p = x - self.a
        p_perp = p - _dot(p, w)[..., None] * w
        dx_perp = dx - _dot(dx, w)[..., None] * w
        t_cyl = _sphere_toi(p_perp, dx_perp, self.radius)  # the infinite cylinder, in its cross-section
        s = _dot(p + jnp.where(jnp.isfinite(t_cyl), t_cyl, 0.0)[..., None] * dx, w)
        t_cyl = jnp.where((s >= 0) & (s <= length), t_cyl, jnp.inf)
        t_a = _sphere_toi(x - self.a, dx, self.radius)
        t_b = _sphere_toi(x - self.b, dx, self.radius)
        return jnp.minimum(t_cyl, jnp.minimum(t_a, t_b))

    def push_out(self, x, gap):
        d = self.distance(x)[..., None]
        return jnp.where(d < gap, self.closest(x) + (self.radius + gap) * self.normal_at(x), x)

    def surface_motion(self, prev: "Capsule", x):
        t, _ = self._param(x)
        _, length = self._axis()
        f = (t / jnp.where(length > 0, length, 1.0))[..., None]
        return (1.0 - f) * (self.a - prev.a) + f * (self.b - prev.b)


COLLIDERS = (Plane, Sphere, Capsule)


def check_colliders(colliders, dtype) -> tuple:
    """A tuple of colliders with every leaf cast to ``dtype`` (``ValueError`` on anything else)."""
    if isinstance(colliders, COLLIDERS):
        colliders = (colliders,)
    if not isinstance(colliders, (tuple, list)):
        raise ValueError(f"colliders must be a tuple of cloth.Plane, cloth.Sphere or cloth.Capsule, got {colliders!r}")
    out = []
    for k, c in enumerate(colliders):
        if not isinstance(c, COLLIDERS):
            raise ValueError(f"colliders[{k}] must be a cloth.Plane, cloth.Sphere or cloth.Capsule, "
                             f"got {type(c).__name__}")
        if is_concrete(*jax.tree_util.tree_leaves(c)):
            check_scene_shapes(c, k, "a per-step path goes to rollout's colliders=")
        out.append(jax.tree_util.tree_map(lambda a: jnp.asarray(a, dtype), c))
    return tuple(out)


#: Each collider's data fields and their shapes in a scene (a path adds a leading axis).
_SHAPES = {Plane: {"normal": (3,), "offset": (), "friction": ()},
           Sphere: {"center": (3,), "radius": (), "friction": ()},
           Capsule: {"a": (3,), "b": (3,), "radius": (), "friction": ()}}
#: Each collider's data fields (its leaves), in order.
SCENE_FIELDS = {kind: tuple(shapes) for kind, shapes in _SHAPES.items()}


def check_scene_shapes(c, k: int, hint: str) -> None:
    """Raise unless every data field of ``colliders[k]`` has its scene shape (no leading
    path or batch axis); ``hint`` ends the message."""
    for f, tail in _SHAPES[type(c)].items():
        if np.shape(getattr(c, f)) != tail:
            raise ValueError(f"colliders[{k}] ({type(c).__name__}) {f} has shape {np.shape(getattr(c, f))}, want "
                             f"{tail} in a scene ({hint})")


def host_distance(c, x) -> np.ndarray:
    """``c.distance(x)`` in float64 numpy, for the boundary checks: no cancellation in
    ``|x - c| - r`` at a float32 scene's precision (a sphere of radius 1e9 m)."""
    x = np.asarray(x, np.float64)
    p = {f: np.asarray(getattr(c, f), np.float64) for f in _SHAPES[type(c)]}
    if isinstance(c, Plane):
        return x @ p["normal"] - p["offset"]
    if isinstance(c, Sphere):
        return np.linalg.norm(x - p["center"], axis=-1) - p["radius"]
    ab = p["b"] - p["a"]
    span = np.linalg.norm(ab)
    w = ab / span if span > 0 else np.zeros(3)
    t = np.clip((x - p["a"]) @ w, 0.0, span)
    return np.linalg.norm(x - (p["a"] + t[..., None] * w), axis=-1) - p["radius"]


def collider_kinds(colliders) -> tuple:
    """``((kind, frictional), ...)``: what a batch or a collider path must share."""
    return tuple((type(c).__name__, c.frictional) for c in colliders)


def count_inside(colliders, x, free) -> list[tuple[int, str, int]]:
    """``(index, kind, count)`` for every collider that holds free particles of ``x (N, 3)``
    inside or on its surface (concrete inputs)."""
    out = []
    for k, c in enumerate(colliders):
        n = int(np.sum((host_distance(c, x) <= 0) & np.asarray(free)))
        if n:
            out.append((k, type(c).__name__, n))
    return out



def describe_inside(inside, what: str) -> str:
    """The error message for :func:`count_inside`'s findings."""
    parts = ", ".join(f"{n} inside colliders[{k}] ({kind})" for k, kind, n in inside)
    return (f"{sum(n for _, _, n in inside)} free particles of the {what} start inside or on a collider ({parts}); "
            "move the cloth or the colliders so that every free particle starts outside")
