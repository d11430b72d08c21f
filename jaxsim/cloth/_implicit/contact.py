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
  ``eps_v h`` (``FRICTION_EPS_V`` m/s, per dtype).  It is convex in ``u``.

Hessian blocks are ``jax.hessian`` of these per-particle terms.  The barrier's block is
``b'' n n^T + b' (Hessian of d)``, and for the convex colliders here the second term is
negative semi-definite with ``n`` in its null space, so its PSD projection is exactly
``(n^T A n) n n^T``; the friction blocks are PSD as they come.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..._dataclass import pytree_dataclass
from ..._dtype import tiny
from .._barrier import _d, barrier, barrier_slope  # noqa: F401 (self-contact and the tests use them here too)
from .._vec import dot, length

#: IPC's friction smoothing velocity ``eps_v`` (m/s) per dtype: tangential speeds below it
#: are treated as static (the friction force ramps from 0 to ``mu lambda`` over it, over the
#: length ``eps_v h``).  Float32's is ten times float64's.  Newton's iterate rounds the
#: displacement ``|u| ~ h |v|`` to ``eps h |v|``, which moves the friction force by about
#: ``mu lambda eps |v| / eps_v``, and the gradient test needs that below ``rtol`` of the
#: forces: at 1e-4 m/s a float32 drape's impacts (1.4 m/s) leave it at 1e-3 of
#: ``mu lambda`` against ``rtol = 1e-4``, and Newton stalls (docs/notebook.md, "float32
#: friction").
FRICTION_EPS_V = {np.dtype(np.float32): 1e-3, np.dtype(np.float64): 1e-4}


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


def runs(colliders) -> list:
    """The colliders in runs of consecutive ones of one kind and friction flag: ``[(start,
    members)]``.  A run of several is evaluated as one ``vmap``ped term (:func:`over`), so
    a body of eleven capsules compiles the code of one."""
    out, i = [], 0
    while i < len(colliders):
        j = i + 1
        key = (type(colliders[i]), colliders[i].frictional)
        while j < len(colliders) and (type(colliders[j]), colliders[j].frictional) == key:
            j += 1
        out.append((i, list(colliders[i:j])))
        i = j
    return out


def over(members, f, *rows):
    """``f(member, *row)`` for each member of a run (colliders, or tuples of them), stacked on
    a leading axis; ``rows``: arrays with a leading axis, one entry per member.  One member is
    evaluated as it is (the program of a scene with one collider per kind is unchanged), a
    run of several under ``jax.vmap``."""
    if len(members) == 1:
        return jax.tree_util.tree_map(lambda a: a[None], f(members[0], *(r[0] for r in rows)))
    treedef = jax.tree_util.tree_structure(members[0])
    leaves = [jnp.stack(ls) for ls in zip(*(jax.tree_util.tree_leaves(m) for m in members))]
    return jax.vmap(lambda ls, *r: f(jax.tree_util.tree_unflatten(treedef, ls), *r))(leaves, *rows)


def _push_out(members, x, free, gap):
    """``x (N, 3)`` with the free particles inside any collider of the run pushed out to
    ``gap``, collider after collider."""
    def one(x, c):
        inside = ((c.distance(x) <= 0) & (free[:, 0] > 0))[:, None]
        return jnp.where(inside, c.push_out(x, gap), x)

    if len(members) == 1:
        return one(x, members[0])
    treedef = jax.tree_util.tree_structure(members[0])
    leaves = [jnp.stack(ls) for ls in zip(*(jax.tree_util.tree_leaves(m) for m in members))]
    return jax.lax.scan(lambda x, ls: (one(x, jax.tree_util.tree_unflatten(treedef, ls)), None), x, leaves)[0]


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
    for _, members in runs(cols):  # a moving collider may have swept over particles: start outside it
        x = _push_out(members, x, free, 0.5 * dhat)
    lam, nrm, slide = [], [], []
    for i, members in runs(cols):
        pairs = [(c, prev[i + k]) for k, c in enumerate(members)]
        if members[0].frictional:
            lam.append(over(pairs, lambda p: cloth.mass * kappa * -barrier_slope(p[0].distance(x), dhat) * free[:, 0]))
        else:
            lam.append(jnp.zeros((len(members),) + cloth.mass.shape, cloth.mass.dtype))
        nrm.append(over(pairs, lambda p: p[0].normal_at(x)))
        slide.append(over(pairs, lambda p: p[0].surface_motion(p[1], x)))
    eps_h = FRICTION_EPS_V[np.dtype(x0.dtype)] * h
    return ContactTerms(kappa=kappa, dhat=dhat, eps_h=eps_h, lam=jnp.concatenate(lam),
                        normal=jnp.concatenate(nrm), slide=jnp.concatenate(slide), start=(x - x0) * free,
                        shift=None if at is None else x0 - at)


def _tangential(ct: ContactTerms, slide, n, u):
    """The tangential motion ``(N, 3)`` relative to a surface that moved by ``slide`` with
    lagged normals ``n`` (one collider's rows of ``ct``)."""
    r = (u if ct.shift is None else u + ct.shift) - slide
    return r - dot(r, n)[..., None] * n


def _rows(ct: ContactTerms, i, count):
    """One run's rows ``(lam, normal, slide)`` of the lagged terms."""
    return ct.lam[i:i + count], ct.normal[i:i + count], ct.slide[i:i + count]


def barrier_energy(u, x0, cloth, ct: ContactTerms, free):
    """``sum_i m_i kappa b(d_i)`` over colliders and free particles (J)."""
    total = 0.0

    def one(c):
        b = barrier(c.distance_from(x0, u), ct.dhat)
        return jnp.sum(jnp.where(free[:, 0] > 0, cloth.mass * b, 0.0))

    for _, members in runs(cloth.colliders):
        total = total + jnp.sum(over(members, one))
    return ct.kappa * total


def friction_energy(u, cloth, ct: ContactTerms):
    """``sum mu lambda f0(|t|)`` over frictional colliders (J); 0 when there are none."""
    total = 0.0

    def one(c, lam, n, slide):
        t = _tangential(ct, slide, n, u)
        return c.friction * jnp.sum(lam * f0(dot(t, t), ct.eps_h))

    for i, members in runs(cloth.colliders):
        if members[0].frictional:
            total = total + jnp.sum(over(members, one, *_rows(ct, i, len(members))))
    return total


def potential(u, x0, cloth, ct: ContactTerms, free):
    """Contact part of the step's potential (J)."""
    return barrier_energy(u, x0, cloth, ct, free) + friction_energy(u, cloth, ct)


def blocks(u, x0, cloth, ct: ContactTerms, free):
    """``(N, 3, 3)`` PSD per-particle Hessian blocks of :func:`potential`.

    From the scalar laws' derivatives by autodiff (the radial form): the barrier's
    projected block is ``m kappa b''(d) n n^T`` (module doc), and friction's is
    ``mu lambda (2 f0' P + 4 f0'' t t^T)`` with ``f0`` a function of ``|t|^2`` and
    ``P = I - n n^T`` (exact, and PSD since the friction potential is convex).
    """
    out = jnp.zeros(u.shape + (3,), u.dtype)

    def one(c, lam, nk, slide):
        b2 = _d(barrier, 2)(c.distance_from(x0, u), ct.dhat)
        n = c.normal_at(x0 + u)
        H = (cloth.mass * ct.kappa * jnp.maximum(b2, 0.0))[:, None, None] * n[:, :, None] * n[:, None, :]
        if c.frictional:
            t = _tangential(ct, slide, nk, u)
            y2 = dot(t, t)
            P = jnp.eye(3, dtype=u.dtype) - nk[:, :, None] * nk[:, None, :]
            F = (2.0 * _d(f0, 1)(y2, ct.eps_h))[:, None, None] * P + (4.0 * _d(f0, 2)(y2, ct.eps_h))[:, None, None] * (
                t[:, :, None] * t[:, None, :])
            H = H + (c.friction * lam)[:, None, None] * F
        return H

    for i, members in runs(cloth.colliders):
        out = out + jnp.sum(over(members, one, *_rows(ct, i, len(members))), axis=0)
    return out * free[:, :, None]


def force_magnitudes(u, x0, cloth, ct: ContactTerms, free):
    """``(N,)`` sum of the barrier and friction force magnitudes at each particle (N)."""
    out = jnp.zeros(u.shape[:1], u.dtype)

    def one(c, lam, nk, slide):
        f = -cloth.mass * ct.kappa * barrier_slope(c.distance_from(x0, u), ct.dhat)
        if c.frictional:
            t = _tangential(ct, slide, nk, u)
            y2 = dot(t, t)
            f1 = 2.0 * jnp.sqrt(y2) * _d(f0, 1)(y2, ct.eps_h)  # d f0 / d|t|, in [0, 1]
            f = f + c.friction * lam * f1
        return f

    for i, members in runs(cloth.colliders):
        out = out + jnp.sum(over(members, one, *_rows(ct, i, len(members))), axis=0)
    return out * free[:, 0]


def step_bound(u, dx, x0, cloth, free):
    """Largest safe step fraction along ``dx``: ``min(1, 0.9 * earliest time of impact)``."""
    x = x0 + u
    t = jnp.ones((), u.dtype)

    def one(c):
        return jnp.min(jnp.where(free[:, 0] > 0, c.time_of_impact(x, dx * free), jnp.inf))

    for _, members in runs(cloth.colliders):
        t = jnp.minimum(t, 0.9 * jnp.min(over(members, one)))
    return t
