"""Wind: aerodynamic drag and lift on the scene's triangles, in a form Newton minimises.

Each triangle ``t`` of area ``A`` and unit normal ``n`` (both frozen at the start of the
step, like the damping directions) moves through air blowing at ``wind`` with the
relative velocity ``q = vbar - wind`` (``vbar`` the mean of its three particles'
velocities), whose normal part is ``r = n . q``.  Two forces act, shared equally by the
three particles (the flat-plate model of Keckeisen et al. 2004, "Interactive cloth
simulation in virtual environments", and Wilson et al. 2014's aerodynamic cloth):

- **drag**, the pressure on the plate, ``-drag A |r| r n`` (``drag``: ``rho C_D / 2``,
  kg/m^3), taken implicitly: with the step's velocity ``v = u / h`` it is minus the
  gradient of the potential ``drag A (h/3) |r|^3`` in the displacements ``u``, which is
  convex and twice differentiable (its Hessian is ``2 drag A |r| / h`` times
  ``(n/3)(n/3)^T`` over the triangle's particles, rank one, ``_rank_one.RankOne``);
- **lift**, across the flow, ``-lift A r (|q|^2 n - r q) / |q|`` (``lift``: ``rho C_L / 2``),
  of size ``lift A |q|^2 cos sin`` of the angle of attack, lagged: computed from the
  velocities at the start of the step and held constant over it (the potential
  ``-F . ubar``).

A scene with ``drag = lift = 0`` compiles none of this (``Cloth.aero``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..._dataclass import pytree_dataclass
from ..._dtype import tiny
from .._rank_one import RankOne


@pytree_dataclass
class AeroTerms:
    """What a step's wind terms freeze at its start (one row per triangle).

    Attributes:
      faces: ``(F, 3)`` int32 particle ids.
      n: ``(F, 3)`` unit normals (0 for a degenerate triangle).
      area: ``(F,)`` areas (m^2).
      wind: ``(3,)`` the air's velocity (m/s).
      drag: ``()`` drag coefficient (kg/m^3).
      lift: ``(F, 3)`` the lagged lift force on each triangle (N).
    """

    faces: jax.Array
    n: jax.Array
    area: jax.Array
    wind: jax.Array
    drag: jax.Array
    lift: jax.Array


def _safe_norm(a):
    s = jnp.sum(a * a, axis=-1)
    ok = s > tiny(a.dtype) ** 2
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, s, 1.0)), 0.0)


def normals(faces, x):
    """``(n (F, 3), area (F,))``: unit normals and areas of the triangles at ``x (N, 3)``
    (NaN-free at degenerate triangles, where ``n = 0``)."""
    a, b, c = x[faces[:, 0]], x[faces[:, 1]], x[faces[:, 2]]
    cr = jnp.cross(b - a, c - a)
    twice = _safe_norm(cr)
    ok = twice > 0
    return jnp.where(ok[:, None], cr / jnp.where(ok, twice, 1.0)[:, None], 0.0), 0.5 * twice


def build(cloth, x0, v0) -> AeroTerms:
    """The step's :class:`AeroTerms` at ``(x0, v0)`` (differentiable in every input)."""
    faces = cloth.contact_faces
    n, area = normals(faces, x0)
    q = jnp.mean(v0[faces], axis=1) - cloth.wind
    r = jnp.sum(n * q, axis=-1)
    speed = _safe_norm(q)
    moving = speed > 0
    across = (speed**2)[:, None] * n - r[:, None] * q
    lift = -(cloth.lift * area * r / jnp.where(moving, speed, 1.0))[:, None] * across
    return AeroTerms(faces, n, area, cloth.wind, cloth.drag, jnp.where(moving[:, None], lift, 0.0))


def _normal_speed(t: AeroTerms, u, h):
    """``(F,)`` ``r = n . (ubar / h - wind)`` for the displacements ``u (N, 3)``."""
    ubar = jnp.mean(u[t.faces], axis=1)
    return jnp.sum(t.n * (ubar / h - t.wind), axis=-1)


def potential(t: AeroTerms, u, h):
    """``()`` the wind's potential (J) at the displacements ``u (N, 3)`` over a step of ``h``."""
    r = _normal_speed(t, u, h)
    drag = t.drag * jnp.sum(t.area * (h / 3.0) * jnp.abs(r) ** 3)
    return drag - jnp.sum(t.lift * jnp.mean(u[t.faces], axis=1))


def force_magnitudes(t: AeroTerms, u, h, N):
    """``(N,)`` the size of the wind forces on each particle (N)."""
    r = _normal_speed(t, u, h)
    f = (t.drag * t.area * r * r + _safe_norm(t.lift)) / 3.0
    return jnp.zeros((N,), u.dtype).at[t.faces].add(f[:, None])


def blocks(t: AeroTerms, u, h, free) -> RankOne:
    """The drag's Hessian blocks at ``u (N, 3)``: ``2 drag A |r| / h (n/3)(n/3)^T`` per
    triangle (rank one, PSD; exact); ``free (N, 1)`` zeroes the pins' rows."""
    r = _normal_speed(t, u, h)
    g = (t.n[:, None, :] / 3.0) * free[t.faces]
    return RankOne(jnp.asarray(t.faces), g.reshape(-1, 9), 2.0 * t.drag * t.area * jnp.abs(r) / h)
