"""The mass-spring scene (a pytree dataclass), its state, and grid builders."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ..._dataclass import is_concrete, pytree_dataclass, static_field
from ..._dtype import as_float, check_array_dtype, check_float_dtype, default_float
from ..._validate import check_finite, check_int, check_positive, check_real, check_shape
from .grids import grid_springs, grid_triangles
from .colliders import check_colliders, count_inside, describe_inside
from .._self.intersect import first_intersection


@pytree_dataclass
class Cloth:
    """A mass-spring system.

    Attributes:
      rest: ``(N, 3)`` rest positions (m).
      springs: ``(S, 2)`` int32 particle ids ``(i, j)`` of each spring: the topology, kept
        as a read-only NumPy array, so that the solver's layout (``_layout.layout_of``) is
        found from it even when the scene is built inside ``jit``.
      rest_length: ``(S,)`` rest lengths ``L`` (m), > 0.
      stiffness: ``(S,)`` spring constants ``k`` (N/m).
      mass: ``(N,)`` particle masses (kg), > 0.
      pinned: ``(N,)`` bool, particles that never move.
      gravity: ``(3,)`` gravitational acceleration (m/s²).
      damping: ``()`` along-spring damping coefficient ``d`` (N·s/m), >= 0.
      damped: static flag, ``damping != 0`` at construction; when False the compiled
        step holds no damping code at all.
      colliders: tuple of ``Plane``, ``Sphere`` and ``Capsule`` (``_model.colliders``); the
        empty default compiles no contact code at all.
      contact_gap: ``()`` IPC barrier distance ``dhat`` (m); default 1e-3 times the
        diagonal of the rest shape's bounding box (``_implicit.contact`` module doc).
      contact_stiffness: ``()`` barrier stiffness per unit mass ``kappa`` (1/s^2), or
        ``None`` (default) for ``(|g| + dhat/h^2) / dhat`` at step ``h``.
      contact_faces: ``(F, 3)`` int32 particle ids of the triangles that self-contact
        keeps apart (read-only NumPy, like ``springs``), or ``None``.
      contact_edges: ``(E, 2)`` their unique edges (derived from the faces).
      self_contact: static flag: IPC's barrier between the scene's own triangles
        (``_self``); the default False compiles no self-contact code at all.
      self_contact_pairs: static number of slots for each kind of pair (point–triangle,
        edge–edge) a step may see (default ``8 N``); a step that finds more says so in
        ``StepInfo.pair_overflow`` and is not converged.
      wind: ``(3,)`` the air's velocity (m/s), or ``None`` (still air); ``rollout(wind=)``
        gives one per step.  A non-zero wind with neither ``drag`` nor ``lift`` given
        raises (it would move nothing); with both given as 0 the scene is still on purpose.
      drag, lift: ``()`` the triangles' aerodynamic drag and lift coefficients
        ``rho C / 2`` (kg/m^3), >= 0, or ``None`` (0) (``_model.aero``); they act on the
        ``contact_faces`` triangles.
      aero: static flag, ``drag`` or ``lift`` nonzero at construction; when False the
        compiled step holds no wind code at all.

    Raises:
      ValueError: on wrong shapes, non-finite values, non-positive masses or rest
        lengths, negative damping, or spring ids out of range.
    """

    rest: jax.Array
    springs: jax.Array
    rest_length: jax.Array
    stiffness: jax.Array
    mass: jax.Array
    pinned: jax.Array
    gravity: jax.Array
    damping: jax.Array
    damped: bool = static_field(default=True)
    colliders: tuple = ()
    contact_gap: jax.Array | None = None
    contact_stiffness: jax.Array | None = None
    contact_faces: jax.Array | None = None
    contact_edges: jax.Array | None = None
    self_contact: bool = static_field(default=False)
    self_contact_pairs: int | None = static_field(default=None)
    wind: jax.Array | None = None
    drag: jax.Array | None = None
    lift: jax.Array | None = None
    aero: bool | None = static_field(default=None)

    def __post_init__(self):
        leaves = (self.rest, self.springs, self.rest_length, self.stiffness, self.mass, self.pinned,
                  self.gravity, self.damping)
        if not is_concrete(*leaves):
            return
        if np.ndim(self.rest) == 3:
            return  # a batch of validated scenes (stack_scenes), checked again by batch_rollout
        rest = check_shape("rest positions", self.rest, (None, 3))
        check_array_dtype("Cloth", rest.dtype)
        N = rest.shape[0]
        if N < 1:
            raise ValueError("a Cloth needs at least one particle")
        check_finite("rest positions", rest)
        springs = np.asarray(self.springs)
        if springs.size == 0:
            springs = springs.reshape(0, 2)
        springs = check_shape("springs", springs, (None, 2))
        if springs.size and not np.issubdtype(springs.dtype, np.integer):
            raise ValueError(f"springs must hold integer particle ids, got dtype {springs.dtype}")
        if springs.size and (springs.min() < 0 or springs.max() >= N):
            raise ValueError(f"spring ids must lie in [0, {N}), got range [{springs.min()}, {springs.max()}]")
        if springs.size and np.any(springs[:, 0] == springs[:, 1]):
            raise ValueError("a spring connects a particle to itself")
        S = springs.shape[0]
        L = check_finite("rest_length", check_shape("rest_length", self.rest_length, (S,)))
        check_positive("rest_length", L)
        k = check_finite("stiffness", check_shape("stiffness", self.stiffness, (S,)))
        check_positive("stiffness", k, strict=False)
        m = check_finite("mass", check_shape("mass", self.mass, (N,)))
        check_positive("mass", m)
        pinned = check_shape("pinned", self.pinned, (N,))
        if pinned.dtype != np.bool_:
            raise ValueError(f"pinned must be a bool mask of shape ({N},); use pin ids with grid() or pin_mask()")
        g = check_finite("gravity", check_shape("gravity", self.gravity, (3,)))
        d = check_finite("damping", check_shape("damping", self.damping, ()))
        check_positive("damping", d, strict=False)
        dtype = jax.dtypes.canonicalize_dtype(rest.dtype) if np.issubdtype(rest.dtype, np.floating) else default_float()
        set_ = object.__setattr__
        set_(self, "rest", as_float(rest, dtype))
        set_(self, "springs", frozen_ids(springs))
        set_(self, "rest_length", as_float(L, dtype))
        set_(self, "stiffness", as_float(k, dtype))
        set_(self, "mass", as_float(m, dtype))
        set_(self, "pinned", jnp.asarray(pinned))
        set_(self, "gravity", as_float(g, dtype))
        set_(self, "damping", as_float(d, dtype))
        set_(self, "damped", bool(self.damped) and float(d) != 0.0)
        set_(self, "colliders", check_colliders(self.colliders, dtype))
        if self.contact_gap is None:
            span = np.ptp(np.asarray(rest, np.float64), axis=0)
            set_(self, "contact_gap", float(np.linalg.norm(span)) * 1e-3 or 1e-3)
        dhat = check_finite("contact_gap", check_shape("contact_gap", self.contact_gap, ()))
        check_positive("contact_gap", dhat)
        set_(self, "contact_gap", as_float(dhat, dtype))
        if self.contact_stiffness is not None:
            kappa = check_finite("contact_stiffness", check_shape("contact_stiffness", self.contact_stiffness, ()))
            check_positive("contact_stiffness", kappa)
            set_(self, "contact_stiffness", as_float(kappa, dtype))
        if self.self_contact or self.contact_faces is not None:
            faces, edges = check_faces(self.contact_faces, N, self.self_contact)
            set_(self, "contact_faces", faces)
            set_(self, "contact_edges", edges)
            cap = check_int("self_contact_pairs", 8 * N if self.self_contact_pairs is None else self.self_contact_pairs, 1)
            set_(self, "self_contact_pairs", cap)
            if self.self_contact:
                hit = first_intersection(np.asarray(rest, np.float64), faces, edges)
                if hit is not None:
                    raise ValueError(f"the rest shape intersects itself: {hit}")
        if self.wind is not None or self.drag is not None or self.lift is not None:
            self._check_aero(N, dtype)
        else:
            set_(self, "aero", False)
        inside = is_concrete(*jax.tree_util.tree_leaves(self.colliders)) and count_inside(
            self.colliders, self.rest, ~np.asarray(pinned))
        if inside:
            raise ValueError(describe_inside(inside, "rest positions"))

    def _check_aero(self, N: int, dtype) -> None:
        """Wind, drag and lift: finite, ``drag, lift >= 0``, and the triangles they act on (a
        non-zero wind with neither drag nor lift given raises: it would move nothing);
        the static ``aero`` flag from their values (``None``: set it from them; traced
        values count as nonzero)."""
        set_ = object.__setattr__
        still = self.drag is None and self.lift is None  # neither given: a wind would move nothing
        given = {"wind": np.zeros(3) if self.wind is None else self.wind,
                 "drag": 0.0 if self.drag is None else self.drag, "lift": 0.0 if self.lift is None else self.lift}
        if not is_concrete(*given.values()):
            set_(self, "aero", True if self.aero is None else bool(self.aero))
            for name, value in given.items():
                set_(self, name, jnp.asarray(value, dtype))
        else:
            for name, value in given.items():
                a = check_finite(name, check_shape(name, value, (3,) if name == "wind" else ()))
                if name != "wind":
                    check_positive(name, a, strict=False)
                set_(self, name, as_float(a, dtype))
            on = float(self.drag) != 0.0 or float(self.lift) != 0.0
            if still and self.aero is None and np.any(np.asarray(self.wind) != 0):
                raise ValueError(f"wind={tuple(float(w) for w in np.asarray(self.wind))} moves nothing without drag or "
                                 "lift: give drag= (flat-plate drag, e.g. 0.3) or lift= as well, as rollout(wind=) "
                                 "needs (drag=0.0 keeps a still scene that ignores the wind)")
            set_(self, "aero", on if self.aero is None else bool(self.aero) or on)
        if self.aero and self.contact_faces is None:
            raise ValueError("drag and lift act on the scene's triangles: build it with grid(..., drag=...) or "
                             "from_mesh(..., drag=...), or pass contact_faces=(F, 3) particle ids")

    @property
    def num_particles(self) -> int:
        return self.rest.shape[-2]

    @property
    def num_springs(self) -> int:
        return self.springs.shape[-2]

    @property
    def dtype(self):
        return self.rest.dtype


def check_faces(faces, N: int, needed: bool):
    """``(faces (F, 3), edges (E, 2))`` as read-only int32 arrays (``ValueError`` when
    self-contact is asked for without faces, or on bad ids)."""
    if faces is None:
        raise ValueError("self_contact=True needs the scene's triangles: build it with grid(..., self_contact=True) "
                         "or from_mesh(..., self_contact=True), or pass contact_faces=(F, 3) particle ids")
    F = check_shape("contact_faces", np.asarray(faces), (None, 3))
    if F.size and not np.issubdtype(F.dtype, np.integer):
        raise ValueError(f"contact_faces must hold integer particle ids, got dtype {F.dtype}")
    if F.size and (F.min() < 0 or F.max() >= N):
        raise ValueError(f"contact_faces ids must lie in [0, {N}), got range [{F.min()}, {F.max()}]")
    if needed and F.shape[0] == 0:
        raise ValueError("self_contact=True needs at least one triangle in contact_faces")
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    return frozen_ids(F), frozen_ids(np.unique(e, axis=0).reshape(-1, 2))


def frozen_ids(ids) -> np.ndarray:
    """``ids`` as a read-only int32 NumPy array (a topology, fixed per scene)."""
    out = np.array(ids, np.int32)
    out.flags.writeable = False
    return out


@pytree_dataclass
class State:
    """Simulation state.

    Attributes:
      x: ``(N, 3)`` positions (m).
      v: ``(N, 3)`` velocities (m/s).
    """

    x: jax.Array
    v: jax.Array

    @staticmethod
    def at_rest(cloth: Cloth) -> "State":
        """Rest positions with zero velocity."""
        return State(cloth.rest, jnp.zeros_like(cloth.rest))


def pin_mask(n_particles: int, ids) -> np.ndarray:
    """Bool mask ``(N,)`` from pin ids, with type and range checks."""
    raw = np.asarray(ids)
    if raw.size and (raw.dtype == np.bool_ or not np.issubdtype(raw.dtype, np.integer)):
        raise ValueError(f"pin ids must be integers (particle indices), got {ids!r}; "
                         "for a boolean mask build the Cloth with pinned=")
    ids = raw.astype(np.int64).reshape(-1)
    if ids.size and (ids.min() < 0 or ids.max() >= n_particles):
        raise ValueError(f"pin ids must lie in [0, {n_particles}), got {ids.tolist()}")
    mask = np.zeros(n_particles, bool)
    mask[ids] = True
    return mask



def grid(n: int, spacing: float = 0.2, *, origin=(0.0, 1.5, -1.0), mass: float = 1.0, stiffness: float = 100.0,
         damping: float = 0.2, gravity: float = 0.3, pins=None, dtype=None, colliders=(),
         contact_gap=None, self_contact: bool = False, self_contact_pairs: int | None = None,
         wind=None, drag: float | None = None, lift: float | None = None) -> Cloth:
    """A square cloth of ``(n+1) x (n+1)`` particles in the plane ``y = origin[1]``.

    Particle ``(i, j)`` (id ``i*(n+1) + j``) starts at ``origin + (spacing*i, 0, spacing*j)``;
    springs are structural, shear and bending (``grid_springs``), rest length = initial
    distance.

    Args:
      n: cells per side (``n >= 1``).
      spacing: particle spacing (m).
      mass: per-particle mass (kg).
      stiffness: spring constant for every spring (N/m).
      damping: along-spring damping ``d`` (N·s/m).
      gravity: magnitude (m/s²) of the acceleration ``(0, -gravity, 0)``.
      pins: pinned particle ids; default the two corners of the first row, ``0`` and ``n``.
      dtype: float dtype (default float32, float64 under ``jax_enable_x64``).
      colliders: ``Plane``/``Sphere``/``Capsule`` tuple (``Cloth.colliders``).
      contact_gap: the barrier distance ``dhat`` (m); default as for :class:`Cloth`.
      self_contact, self_contact_pairs: as for :class:`Cloth` (the triangles are
        ``grid_triangles(n)``).
      wind, drag, lift: as for :class:`Cloth` (on the same triangles).
    """
    n = check_int("grid n (cells per side)", n, 1)
    spacing = check_real("spacing", spacing, minimum=0.0, strict=True)
    for name, val in (("mass", mass), ("stiffness", stiffness), ("damping", damping), ("gravity", gravity)):
        check_real(name, val)
    if np.ndim(origin) != 1 or np.shape(origin) != (3,):
        raise ValueError(f"origin must be 3 numbers, got {origin!r}")
    m = n + 1
    ii, jj = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    rest = np.stack([spacing * ii, np.zeros_like(ii, float), spacing * jj], -1).reshape(-1, 3) + np.asarray(origin)
    springs, _ = grid_springs(n)
    L = np.linalg.norm(rest[springs[:, 1]] - rest[springs[:, 0]], axis=-1)
    dtype = default_float() if dtype is None else check_float_dtype("grid", dtype)
    pins = [0, n] if pins is None else pins
    return Cloth(
        rest=np.asarray(rest, dtype), springs=springs, rest_length=np.asarray(L, dtype),
        stiffness=np.full(len(springs), stiffness, dtype), mass=np.full(m * m, mass, dtype),
        pinned=pin_mask(m * m, pins), gravity=np.asarray([0.0, -gravity, 0.0], dtype),
        damping=np.asarray(damping, dtype), colliders=colliders, contact_gap=contact_gap,
        contact_faces=grid_triangles(n) if self_contact or drag or lift else None, self_contact=bool(self_contact),
        self_contact_pairs=self_contact_pairs, wind=wind, drag=drag, lift=lift,
    )


def lab_cloth(dtype=None) -> Cloth:
    """The lab's cloth: 11 x 11 particles, spacing 0.2, 618 springs, k=100, d=0.2, g=0.3, pins 0 and 10."""
    return grid(10, 0.2, dtype=dtype)


def replace(cloth: Cloth, **kw) -> Cloth:
    """``dataclasses.replace`` for scenes.

    Scalars given for the per-spring ``stiffness``/``rest_length`` or the per-particle
    ``mass`` are broadcast to ``(S,)``/``(N,)`` in the scene's dtype, and a new
    ``damping`` sets the static ``damped`` flag (so a zero damping can still be traced).
    ``self_contact=True`` needs the scene's triangles: a scene built with them
    (``grid``/``from_mesh(..., self_contact=True)``), or ``contact_faces=`` given too; so
    do ``drag`` and ``lift`` (``grid``/``from_mesh(..., drag=...)``).  A new ``drag`` or
    ``lift`` sets the static ``aero`` flag from the new values.
    """
    shapes = {"stiffness": (cloth.num_springs,), "rest_length": (cloth.num_springs,), "mass": (cloth.num_particles,)}
    for name, shape in shapes.items():
        if name in kw and np.ndim(kw[name]) == 0:
            kw[name] = jnp.full(shape, kw[name], cloth.dtype)
    if "damping" in kw and "damped" not in kw:
        kw["damped"] = True
    if ("drag" in kw or "lift" in kw) and "aero" not in kw:
        kw["aero"] = None  # set again from the new values
    return dataclasses.replace(cloth, **kw)
