"""The cloth's potential, defined once per spring element, and what derives from it.

``energy(cloth, x) = sum_s k_s/2 (|x_j - x_i| - L_s)^2 - sum_i m_i g . x_i`` (springs plus
gravity).  Forces are ``-jax.grad(energy)``; the implicit step's per-spring Hessian
blocks come from the scalar spring law's derivatives by autodiff (the radial form).
``spring_hessian`` is the lab's analytic Hessian (17.27), kept only to cross-check the
autodiff one.

Implicit damping.  The along-spring damping force on particle ``i`` of spring ``(i, j)``
is ``f = d (v_ij . e) e`` with ``v_ij = v_j - v_i``, ``e`` the unit spring direction.
Freezing ``e = e^n`` at the start of the step and putting ``v = (x - x^n)/h`` gives
``f = -grad D(x)`` for the dissipation potential

    D(x) = sum_s d/(2h) (e_s^n . ((x_j - x_i) - (x_j^n - x_i^n)))^2,

so backward Euler with damping is still the minimisation of an incremental potential
(17.19) with ``D`` added; ``D`` is quadratic with PSD blocks ``(d/h) e e^T``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._layout import spring_diff
from .scene import Cloth
from .._vec import dot
from .._vec import length as _length
from .._vec import stretch_increment


def spring_potential(stretch, k):
    """The spring law, ``psi(s) = k/2 s^2`` (J) of a spring stretched by ``s = l - L`` (m).

    Every spring energy in the package (the scene's ``energy``, the implicit step's
    incremental potential, the Hessian blocks) is this one function.
    """
    return 0.5 * k * stretch * stretch


def element_potential(stretch, k, damp=None, d_over_h=None):
    """Potential of one spring in the implicit step (J) from its stretch ``s`` (m) and,
    when damped, its change ``damp = e0 . dd`` along the frozen direction (m):
    ``psi(s) + d/(2h) damp^2`` (module doc)."""
    v = spring_potential(stretch, k)
    if damp is not None:
        v = v + 0.5 * d_over_h * damp * damp
    return v


def step_element(dd, d0, l0, s0, k, e0=None, d_over_h=None):
    """Potential of one spring in the implicit step, as a function of ``dd = du_j - du_i``.

    :func:`element_potential` of the stretch ``s0 + (|d0 + dd| - l0)`` and, when ``e0``
    is given, of ``e0 . dd``.  ``s0 = l0 - L`` is the stretch at the start of the step.
    """
    return element_potential(s0 + stretch_increment(d0, l0, dd), k, None if e0 is None else dot(e0, dd), d_over_h)


def spring_energy(cloth: Cloth, x, layout=None):
    """Total spring energy (J) at positions ``x (N, 3)`` (``layout``: ``_layout``, default gathers)."""
    return jnp.sum(spring_potential(_length(spring_diff(cloth, x, layout)) - cloth.rest_length, cloth.stiffness))


def gravity_energy(cloth: Cloth, x):
    """Gravitational potential ``-sum m g . x`` (J)."""
    return -jnp.sum(cloth.mass[:, None] * cloth.gravity * x)


def energy(cloth: Cloth, x, layout=None):
    """The potential energy (J): springs plus gravity.  Shape ``(N, 3) -> ()``."""
    return spring_energy(cloth, x, layout) + gravity_energy(cloth, x)


def forces(cloth: Cloth, x, layout=None):
    """Conservative forces ``-grad energy`` (N), ``(N, 3)``."""
    return -jax.grad(energy, argnums=1)(cloth, x, layout)


def kinetic_energy(cloth: Cloth, v):
    return 0.5 * jnp.sum(cloth.mass[:, None] * v * v)


def total_energy(cloth: Cloth, x, v, layout=None):
    """Kinetic + spring + gravity energy (J)."""
    return kinetic_energy(cloth, v) + energy(cloth, x, layout)


def spring_directions(cloth: Cloth, x, layout=None):
    """Unit directions ``e (S, 3)`` and vectors ``x_j - x_i (S, 3)`` of every spring."""
    d = spring_diff(cloth, x, layout)
    n = _length(d)[:, None]
    return jnp.where(n > 0, d / jnp.where(n > 0, n, 1.0), 0.0), d


def radial_parts(d, s, k):
    """The spring blocks' two eigenvalues, from the spring law's derivatives by autodiff.

    A spring's potential depends on its length ``l = |d|`` only, so its 3x3 block is
    ``A = psi''(s) e e^T + psi'(s)/l (I - e e^T)`` with ``e = d / l`` and ``s = l - L``:
    ``psi'`` and ``psi''`` are scalar ``jax.grad``s of :func:`spring_potential`,
    elementwise over the springs (no 3x3 Hessian per spring is traced).

    Args:
      d: ``(S, 3)`` spring vectors (m).
      s: ``(S,)`` stretches (m).
      k: ``(S,)`` stiffnesses (N/m).

    Returns:
      ``(e (S, 3), dpsi (S,), along (S,), across (S,))``: the unit directions (0 for a
      zero-length spring), ``psi'`` (N), ``psi''`` (N/m) and ``psi'/l`` (N/m, 0 at zero
      length).
    """
    dpsi = jax.grad(spring_potential)
    d2psi = jax.grad(dpsi)
    along = jax.vmap(d2psi)(s, k)
    l = _length(d)
    ok = l > 0
    safe = jnp.where(ok, l, 1.0)
    e = jnp.where(ok[:, None], d / safe[:, None], 0.0)
    slope = jax.vmap(dpsi)(s, k)
    across = jnp.where(ok, slope / safe, 0.0)
    return e, slope, along, across


def radial_blocks(e, along, across, e0=None, d_over_h=None, *, project_psd: bool):
    """``(S, 3, 3)`` blocks ``along e e^T + across (I - e e^T)`` (+ damping ``(d/h) e0 e0^T``).

    With ``project_psd`` both eigenvalues are clamped at 0: the exact PSD projection of
    the spring block, since ``e e^T`` and ``I - e e^T`` are orthogonal projectors (a
    compressed spring has ``across = k (1 - L/l) < 0``).  The damping block is PSD.
    """
    if project_psd:
        along, across = jnp.maximum(along, 0.0), jnp.maximum(across, 0.0)
    eeT = e[:, :, None] * e[:, None, :]
    A = (along - across)[:, None, None] * eeT + across[:, None, None] * jnp.eye(3, dtype=e.dtype)
    if e0 is not None:
        A = A + d_over_h * (e0[:, :, None] * e0[:, None, :])
    return A


def blocks_from_elements(d0, l0, s0, k, dd, e0=None, d_over_h=None, *, project_psd: bool):
    """Per-spring 3x3 blocks ``A_s``: the Hessian of :func:`step_element` at ``dd``.

    Each element potential depends on ``x_j - x_i`` only, so its 6x6 Hessian is
    ``[[A, -A], [-A, A]]``; ``A`` comes in the radial form of :func:`radial_parts`
    (equal to ``jax.hessian`` of the element, tested to 1e-12).  For the quadratic spring
    ``A = k e e^T + k (1 - L/l)(I - e e^T)``; ``project_psd`` clamps the perpendicular
    eigenvalue ``k (1 - L/l)`` at 0 (:func:`radial_blocks`).

    Args:
      d0, l0, s0, k: ``(S, 3)``, ``(S,)``, ``(S,)``, ``(S,)`` as for :func:`step_element`.
      dd: ``(S, 3)`` where to evaluate.
      e0, d_over_h: ``(S, 3)`` and ``()`` damping terms, or ``None``.

    Returns:
      ``(S, 3, 3)`` blocks.
    """
    e, _, along, across = radial_parts(d0 + dd, s0 + stretch_increment(d0, l0, dd), k)
    return radial_blocks(e, along, across, e0, d_over_h, project_psd=project_psd)


def element_blocks(cloth: Cloth, x, damping_terms=None, *, project_psd: bool):
    """Per-spring 3x3 blocks ``A_s`` of the potential's Hessian at positions ``x (N, 3)``.

    See :func:`blocks_from_elements`.

    Args:
      damping_terms: ``(e0 (S,3), d01_0 (S,3), d/h)`` to add the implicit damping blocks.

    Returns:
      ``(S, 3, 3)`` blocks.
    """
    _, d = spring_directions(cloth, x)
    l = _length(d)
    e0, doh = (None, None) if damping_terms is None else (damping_terms[0], damping_terms[2])
    return blocks_from_elements(d, l, l - cloth.rest_length, cloth.stiffness, jnp.zeros_like(d), e0, doh,
                                project_psd=project_psd)


def assemble(cloth: Cloth, blocks):
    """Dense ``(3N, 3N)`` matrix from per-spring blocks (17.28): ``+A`` on the diagonal
    blocks ``ii``, ``jj`` and ``-A`` on ``ij``, ``ji``."""
    N = cloth.num_particles
    i, j = cloth.springs[:, 0], cloth.springs[:, 1]
    H = jnp.zeros((N, N, 3, 3), blocks.dtype)
    H = H.at[i, i].add(blocks).at[j, j].add(blocks).at[i, j].add(-blocks).at[j, i].add(-blocks)
    return H.transpose(0, 2, 1, 3).reshape(3 * N, 3 * N)


def spring_hessian(cloth: Cloth, x):
    """The lab's analytic spring Hessian (17.27), for cross-checks.

    ``H_e = k e e^T + k (1 - L/l)(I - e e^T)`` per spring, placed as in (17.28).

    Returns:
      ``(dense (3N, 3N), blocks (S, 3, 3))``.
    """
    i, j = cloth.springs[:, 0], cloth.springs[:, 1]
    d = x[j] - x[i]
    l = jnp.linalg.norm(d, axis=-1)
    e = d / l[:, None]
    k, L = cloth.stiffness, cloth.rest_length
    eeT = e[:, :, None] * e[:, None, :]
    blocks = k[:, None, None] * eeT + (k * (1 - L / l))[:, None, None] * (jnp.eye(3, dtype=x.dtype) - eeT)
    return assemble(cloth, blocks), blocks
