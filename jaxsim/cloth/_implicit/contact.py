"""Particle–collider contact in the incremental potential: IPC's barrier and lagged friction.

Li et al. 2020, "Incremental Potential Contact" (IPC):

- **Barrier (§4, eq. 6).**  Each free particle ``i`` and collider adds
  ``m_i kappa b(d)`` to the step's potential, with ``d`` the signed distance and
  ``b(d) = -(d - dhat)^2 log(d / dhat)`` for ``0 < d < dhat``, 0 beyond and ``+inf`` at
  ``d <= 0``.  ``dhat`` is ``Cloth.contact_gap`` (default 1e-3 times the rest shape's
  bounding-box diagonal, IPC's default).  ``kappa`` (1/s^2, per unit mass) is
  ``Cloth.contact_stiffness``, by default ``(|g| + dhat/h^2) / dhat``: at ``d = dhat/2``
  the barrier then pushes with ``1.19 m (|g| + dhat/h^2)``, a particle's weight plus the
  force that stops a motion of ``dhat`` within one step.  The barrier only shapes how
  close a contact rests; it never lets a particle through, whatever ``kappa``.
- **No crossing (§4.3).**  Every Newton step is capped at 0.9 of the earliest time of
  impact along it (closed form per collider), so the barrier is never jumped over; the
  line search then only ever evaluates positions outside every collider.
- **Friction (§5).**  Lagged smooth Coulomb friction: the normal force
  ``lambda = -m kappa b'(d)`` and the normal at the start of the step are frozen, and the
  tangential motion ``t = (I - n n^T)(u - s)`` relative to the surface (which moved by
  ``s``) costs ``mu lambda f0(|t|)`` with IPC's ``f0`` (eq. 15), smoothed over
  ``eps_v h`` (``FRICTION_EPS_V`` m/s).  It is convex in ``u``.

Hessian blocks are ``jax.hessian`` of these per-particle terms.  The barrier's block is
``b'' n n^T + b' (Hessian of d)``, and for the convex colliders here the second term is
negative semi-definite with ``n`` in its null space, so its PSD projection is exactly
``(n^T A n) n n^T``; the friction blocks are PSD as they come.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..._dataclass import pytree_dataclass
from ..._dtype import tiny
from .._vec import dot, length

#: IPC's friction smoothing velocity ``eps_v`` (m/s): tangential speeds below it are
#: treated as static (the friction force ramps from 0 to ``mu lambda`` over it).
FRICTION_EPS_V = 1e-4


def barrier(d, dhat):
    """IPC's ``b(d)`` (m^2): ``-(d - dhat)^2 log(d / dhat)`` on ``(0, dhat)``, 0 beyond,
    ``+inf`` at ``d <= 0``; NaN-free gradient everywhere (double ``where``)."""
    active = (d > 0) & (d < dhat)
    ds = jnp.where(active, d, dhat)
    val = -(ds - dhat) ** 2 * jnp.log(ds / dhat)
    return jnp.where(d > 0, jnp.where(active, val, 0.0), jnp.inf)


def barrier_slope(d, dhat):
    """``b'(d)`` (m), ``<= 0``: ``-(d - dhat)(2 log(d/dhat) + (d - dhat)/d)`` on ``(0, dhat)``."""
    active = (d > 0) & (d < dhat)
    ds = jnp.where(active, d, dhat)
    return jnp.where(active, -(ds - dhat) * (2.0 * jnp.log(ds / dhat) + (ds - dhat) / ds), 0.0)


def f0(y2, eps_h):
    """IPC's smoothed ``|t|`` (m) from ``y2 = |t|^2``: ``-y^3/(3 e^2) + y^2/e + e/3`` for
    ``y < e = eps_v h``, ``y`` beyond (eq. 15; convex, twice differentiable)."""
    pos = y2 > tiny(y2.dtype) ** 2
    y = jnp.where(pos, jnp.sqrt(jnp.where(pos, y2, 1.0)), 0.0)
    inner = y2 < eps_h * eps_h
    ys = jnp.where(inner, y, eps_h)
    smooth = -ys * y2 / (3.0 * eps_h * eps_h) + y2 / eps_h + eps_h / 3.0
    big = jnp.where(inner, eps_h, y2)
    return jnp.where(inner, smooth, jnp.sqrt(big))


@pytree_dataclass
class ContactTerms:
    """What a step's contact terms freeze at its start (one row per collider).

    Attributes:
      kappa: ``()`` barrier stiffness per unit mass (1/s^2).
      dhat: ``()`` barrier distance (m).
      eps_h: ``()`` friction smoothing length ``eps_v h`` (m).
      lam: ``(C, N)`` lagged normal force magnitudes (N); zero rows for frictionless colliders.
      normal: ``(C, N, 3)`` lagged unit normals.
      slide: ``(C, N, 3)`` surface motion over the step next to each particle (m).
      start: ``(N, 3)`` feasible start displacement (nonzero only where a moving collider
        swept over a particle: it is pushed out to ``dhat / 2``; BDF2's: back to ``x^n``).
      shift: ``(N, 3)`` ``x_b - x^n``, the offset of the problem's base from the step's
        start (BDF2's shifted state, ``_implicit.bdf2``), or ``None`` (backward Euler: 0).
    """

    kappa: jax.Array
    dhat: jax.Array
    eps_h: jax.Array
    lam: jax.Array
    normal: jax.Array
    slide: jax.Array
    start: jax.Array
    shift: jax.Array | None = None


def default_stiffness(cloth, h):
    """``(|g| + dhat/h^2) / dhat`` (1/s^2), see the module doc."""
    dhat = cloth.contact_gap
    return (length(cloth.gravity) + dhat / h**2) / dhat


def build(cloth, x0, h, free, prev=None, at=None) -> ContactTerms:
    """Lagged terms for a step of ``h`` (s) whose problem is built on ``x0 (N, 3)``.

    ``prev``: the colliders at the start of the step (default: the scene's, i.e. static).
    ``at``: the positions ``x^n`` at the start of the step where ``x0`` is not them
    (BDF2's shifted base ``x_b``, which may lie inside a collider): the terms are lagged
    at ``x^n``, Newton starts there, and friction's tangential motion is ``x - x^n``
    relative to the surface, as in backward Euler's step."""
    cols = cloth.colliders
    prev = cols if prev is None else prev
    dhat = cloth.contact_gap
    kappa = default_stiffness(cloth, h) if cloth.contact_stiffness is None else cloth.contact_stiffness
    x = x0 if at is None else at
    for c in cols:  # a moving collider may have swept over particles: start outside it
        inside = ((c.distance(x) <= 0) & (free[:, 0] > 0))[:, None]
        x = jnp.where(inside, c.push_out(x, 0.5 * dhat), x)
    lam, nrm, slide = [], [], []
    for c, c0 in zip(cols, prev):
        if c.frictional:
            lam.append(cloth.mass * kappa * -barrier_slope(c.distance(x), dhat) * free[:, 0])
        else:
            lam.append(jnp.zeros_like(cloth.mass))
        nrm.append(c.normal_at(x))
        slide.append(c.surface_motion(c0, x))
    return ContactTerms(kappa=kappa, dhat=dhat, eps_h=FRICTION_EPS_V * h, lam=jnp.stack(lam), normal=jnp.stack(nrm),
                        slide=jnp.stack(slide), start=(x - x0) * free, shift=None if at is None else x0 - at)


def _tangential(ct: ContactTerms, k, u):
    r = (u if ct.shift is None else u + ct.shift) - ct.slide[k]
    n = ct.normal[k]
    return r - dot(r, n)[..., None] * n


def barrier_energy(u, x0, cloth, ct: ContactTerms, free):
    """``sum_i m_i kappa b(d_i)`` over colliders and free particles (J)."""
    total = 0.0
    for c in cloth.colliders:
        b = barrier(c.distance_from(x0, u), ct.dhat)
        total = total + jnp.sum(jnp.where(free[:, 0] > 0, cloth.mass * b, 0.0))
    return ct.kappa * total


def friction_energy(u, cloth, ct: ContactTerms):
    """``sum mu lambda f0(|t|)`` over frictional colliders (J); 0 when there are none."""
    total = 0.0
    for k, c in enumerate(cloth.colliders):
        if c.frictional:
            t = _tangential(ct, k, u)
            total = total + c.friction * jnp.sum(ct.lam[k] * f0(dot(t, t), ct.eps_h))
    return total


def potential(u, x0, cloth, ct: ContactTerms, free):
    """Contact part of the step's potential (J)."""
    return barrier_energy(u, x0, cloth, ct, free) + friction_energy(u, cloth, ct)


def _d(f, order):
    """Elementwise ``order``-th derivative of a scalar function ``f(x, c)`` in ``x``."""
    for _ in range(order):
        f = jax.grad(f)
    return jnp.vectorize(f, excluded={1})


def blocks(u, x0, cloth, ct: ContactTerms, free):
    """``(N, 3, 3)`` PSD per-particle Hessian blocks of :func:`potential`.

    From the scalar laws' derivatives by autodiff (the radial form): the barrier's
    projected block is ``m kappa b''(d) n n^T`` (module doc), and friction's is
    ``mu lambda (2 f0' P + 4 f0'' t t^T)`` with ``f0`` a function of ``|t|^2`` and
    ``P = I - n n^T`` (exact, and PSD since the friction potential is convex).
    """
    out = jnp.zeros(u.shape + (3,), u.dtype)
    for k, c in enumerate(cloth.colliders):
        b2 = _d(barrier, 2)(c.distance_from(x0, u), ct.dhat)
        n = c.normal_at(x0 + u)
        out = out + (cloth.mass * ct.kappa * jnp.maximum(b2, 0.0))[:, None, None] * n[:, :, None] * n[:, None, :]
        if c.frictional:
            t = _tangential(ct, k, u)
            y2 = dot(t, t)
            nk = ct.normal[k]
            P = jnp.eye(3, dtype=u.dtype) - nk[:, :, None] * nk[:, None, :]
            H = (2.0 * _d(f0, 1)(y2, ct.eps_h))[:, None, None] * P + (4.0 * _d(f0, 2)(y2, ct.eps_h))[:, None, None] * (
                t[:, :, None] * t[:, None, :])
            out = out + (c.friction * ct.lam[k])[:, None, None] * H
    return out * free[:, :, None]


def force_magnitudes(u, x0, cloth, ct: ContactTerms, free):
    """``(N,)`` sum of the barrier and friction force magnitudes at each particle (N)."""
    out = jnp.zeros(u.shape[:1], u.dtype)
    for k, c in enumerate(cloth.colliders):
        out = out - cloth.mass * ct.kappa * barrier_slope(c.distance_from(x0, u), ct.dhat)
        if c.frictional:
            t = _tangential(ct, k, u)
            y2 = dot(t, t)
            f1 = 2.0 * jnp.sqrt(y2) * _d(f0, 1)(y2, ct.eps_h)  # d f0 / d|t|, in [0, 1]
            out = out + c.friction * ct.lam[k] * f1
    return out * free[:, 0]


def step_bound(u, dx, x0, cloth, free):
    """Largest safe step fraction along ``dx``: ``min(1, 0.9 * earliest time of impact)``."""
    x = x0 + u
    t = jnp.ones((), u.dtype)
    for c in cloth.colliders:
        toi = jnp.where(free[:, 0] > 0, c.time_of_impact(x, dx * free), jnp.inf)
        t = jnp.minimum(t, 0.9 * jnp.min(toi))
    return t
