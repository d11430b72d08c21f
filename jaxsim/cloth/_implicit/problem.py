"""One implicit step as a minimisation problem in the step's deviation from inertia.

Backward Euler's positions minimise the incremental potential (17.19).  Its unknown here
is ``w = x - x^n - y``, the deviation of the step's displacement ``u = x - x^n`` from the
prediction ``y = h v^n + h^2 g`` of inertia and gravity alone:

    g(w) = 1/(2h^2) |w|_M^2 + sum_s psi(s0_s + (|d0_s + du_s| - l0_s)) + D(w)

with ``d0 = x^n_j - x^n_i``, ``l0 = |d0|``, ``s0 = l0 - L``, the spring's change
``du_s = h (v^n_j - v^n_i) + (w_j - w_i)`` and ``D`` the frozen-direction damping potential
(``_model.energy`` module doc); gravity is in ``y`` (``1/(2h^2)|u - h v^n|^2_M - m g . u`` is
``1/(2h^2)|w|^2_M`` plus a constant).  ``g`` differs from (17.19) by a constant only, but
every term is computed from the motion itself, and the unknown is the part of the motion
that the springs (and colliders) decide.  The precision of the solve is relative to
``|w|``: float32 resolves a spring's change to about ``eps |w|`` rather than ``eps |u|``
(with stiff springs the difference decides whether the gradient test can be met at all),
and the new velocity is ``v = v^n + h g + w / h``.  (With ``x`` as the unknown, float32 cannot represent a step
shorter than ``eps |x|``, about 1e-7 m at the lab's scale; the cloth then freezes at
small ``dt``.)
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from ..._dataclass import pytree_dataclass
from ..._dtype import tiny
from ..._fusion import materialized
from . import contact as ct
from .._model import aero as aero_
from .._model import energy as en
from .._layout import Layout, layout_of
from .._model.scene import Cloth
from .._self import terms as sc
from .._vec import dot
from .parts import ContactParts, contact_parts, others  # noqa: F401  (ContactParts, contact_parts: as ``problem``'s)


def free_mask(cloth: Cloth, dtype) -> jax.Array:
    """``(N, 1)`` 1.0 for free particles, 0.0 for pinned ones."""
    return (~cloth.pinned)[:, None].astype(dtype)


@pytree_dataclass
class StepProblem:
    """Everything one implicit step depends on, computed once per step.

    Attributes:
      cloth: the scene (an undamped scene has its ``damping`` leaf replaced by 0 so the
        compiled step never reads it).
      layout: how the springs are walked (``_layout``: ``PlanarLayout`` or ``ParticleLayout``).
      x0: ``(N, 3)`` positions ``x^n`` (m).
      v0: ``(N, 3)`` velocities ``v^n`` (m/s).
      h: ``()`` time step (s).
      d0: ``(S, 3)`` spring vectors ``x^n_j - x^n_i`` (m).
      l0: ``(S,)`` their lengths (m).
      s0: ``(S,)`` stretches ``l0 - L`` (m).
      dv: ``(S, 3)`` the springs' change under the inertial prediction, ``h (v^n_j - v^n_i)`` (m).
      e0: ``(S, 3)`` frozen unit damping directions ``d0 / l0`` (``None`` when undamped).
      contact: the lagged contact terms (``_implicit.contact.ContactTerms``), ``None`` for a scene
        without colliders.
      selfc: the self-contact data (``_self.terms.SelfContact``), ``None`` unless
        ``Cloth.self_contact``.
      pin_to: ``(N, 3)`` where the pinned particles are at the end of the step (m; other
        rows unused), or ``None``: pins stay at ``x^n``.
      aero: the wind's terms frozen at the step's start (``_model.aero.AeroTerms``),
        ``None`` unless ``Cloth.aero``.
    """

    cloth: Cloth
    layout: Layout
    x0: jax.Array
    v0: jax.Array
    h: jax.Array
    d0: jax.Array
    l0: jax.Array
    s0: jax.Array
    dv: jax.Array
    e0: jax.Array | None
    contact: ct.ContactTerms | None = None
    selfc: sc.SelfContact | None = None
    pin_to: jax.Array | None = None
    aero: aero_.AeroTerms | None = None

    @staticmethod
    def build(cloth: Cloth, x0, v0, h, prev_colliders=None, layout: Layout | None = None,
              start=None, pins=None) -> "StepProblem":
        """Derive the per-step terms (differentiable in every input).

        ``prev_colliders``: the colliders at the start of the step when they move (the
        scene holds those at its end); default static.  ``layout``: the scene's
        (``_layout.layout_of``, built here when ``None``).  ``start``: ``(x^n (N, 3),
        step ())`` where the problem is not built on the step's own start and length
        (BDF2's, ``_implicit.bdf2.step_problem``): the contact terms are those of the
        step from ``x^n`` over ``step`` seconds (``_implicit.contact.build``).  ``pins``:
        ``(N, 3)`` the pinned particles' positions at the end of the step (moving pins;
        other rows unused), or ``None``."""
        layout = layout_of(cloth.springs, cloth.rest) if layout is None else layout
        if not cloth.damped:
            cloth = dataclasses.replace(cloth, damping=jnp.zeros((), x0.dtype))
        d0 = layout.diff(cloth.springs, x0)
        l0 = en._length(d0)
        e0 = None
        if cloth.damped:
            ok = (l0 > 0)[:, None]
            e0 = jnp.where(ok, d0 / jnp.where(ok, l0[:, None], 1.0), 0.0)  # as en.spring_directions
        contact = None
        if cloth.colliders:
            at, step = (None, h) if start is None else start
            contact = ct.build(cloth, x0, step, free_mask(cloth, x0.dtype), prev_colliders, at)
        selfc = None
        if cloth.self_contact:
            kappa = ct.default_stiffness(cloth, h) if cloth.contact_stiffness is None else cloth.contact_stiffness
            selfc = sc.build(cloth, kappa)
        wind = aero_.build(cloth, x0, v0) if cloth.aero else None
        return StepProblem(cloth, layout, x0, v0, h, d0, l0, l0 - cloth.rest_length,
                           h * layout.diff(cloth.springs, v0), e0, contact, selfc, pins, wind)

    @property
    def has_others(self) -> bool:
        """Terms besides inertia and springs: colliders, self-contact or wind (``parts``)."""
        return self.contact is not None or self.selfc is not None or self.aero is not None

    @property
    def touches(self) -> bool:
        """Contact terms of any kind (colliders or self-contact): Newton starts from ``x^n``
        (or its push-out), never from an extrapolation that might cross a surface."""
        return self.contact is not None or self.selfc is not None

    def with_pairs(self, pairs):
        """The problem with its self-contact pair set fixed to ``pairs`` (``_self.terms.PairSet``)."""
        if self.selfc is None or pairs is None:
            return self
        return dataclasses.replace(self, selfc=dataclasses.replace(self.selfc, pairs=pairs))

    def positions(self, w):
        """``(N, 3)`` the positions ``x^n + u`` at the deviation ``w`` (m)."""
        return self.x0 + self.displacement(w)

    @property
    def free(self) -> jax.Array:
        """``(N, 1)`` 1.0 for free particles, 0.0 for pinned ones (in the scene's dtype)."""
        return free_mask(self.cloth, self.x0.dtype)

    @property
    def start(self) -> jax.Array:
        """``(N, 3)`` Newton's first iterate ``w``: the displacement 0 (the lab's linearisation
        point), or the push-out off a moving collider."""
        u = jnp.zeros_like(self.x0) if self.contact is None else self.contact.start
        if self.pin_to is None:
            return u - self.prediction
        return jnp.where(self.free > 0, u - self.prediction, self.pinned_at)

    @property
    def pinned_at(self) -> jax.Array:
        """``(N, 3)`` the deviation ``w`` that puts the pinned particles where they are at the
        end of the step: ``-y`` (they stay at ``x^n``), or ``pin_to - x^n - y`` (moving pins);
        read on pinned rows only."""
        if self.pin_to is None:
            return -self.prediction
        return (self.pin_to - self.x0) - self.prediction

    @property
    def prediction(self) -> jax.Array:
        """``(N, 3)`` the displacement ``y = h v^n + h^2 g`` under inertia and gravity alone (m)."""
        return self.h * self.v0 + self.h**2 * self.cloth.gravity

    def displacement(self, w):
        """``u = y + w`` (N, 3) (m)."""
        return self.prediction + w

    def velocity(self, w):
        """``v = u / h = v^n + h g + w / h`` (N, 3) (m/s), from the deviation itself rather
        than from a rounded displacement."""
        return self.v0 + self.h * self.cloth.gravity + w / self.h

    @property
    def d_over_h(self):
        return self.cloth.damping / self.h

    def spring_change(self, w):
        """``(S, 3)`` change ``h (v^n_j - v^n_i) + (w_j - w_i)`` of every spring vector (m)."""
        return self.dv + self.layout.diff(self.cloth.springs, w)

    def sum(self, f, signed: bool = True):
        """Per-particle sums of per-spring values ``f (S, ...) -> (N, ...)`` (``_layout``)."""
        return self.layout.sum(self.cloth.springs, f, signed)


@pytree_dataclass
class SpringTerms:
    """The springs' share of ``g`` at one ``w``, computed once and shared by the objective,
    its gradient, the force scale and the Hessian blocks.

    A spring's potential depends on its length only, so everything Newton needs from it
    follows from the scalar spring law's derivatives (``jax.grad`` of
    ``_model.energy.spring_potential``) and the unit direction: the force on the spring's
    second end is ``psi'(s) e`` (the radial form of the gradient; ``_model.energy.radial_parts``
    is that of the Hessian blocks), plus the damping force ``(d/h)(e0 . dd) e0``.

    Attributes:
      e: ``(S, 3)`` unit spring directions (0 for a zero-length spring).
      s: ``(S,)`` stretches ``l - L`` (m).
      dpsi: ``(S,)`` ``psi'(s)`` (N).
      along: ``(S,)`` ``psi''(s)`` (N/m).
      across: ``(S,)`` ``psi'(s) / l`` (N/m; 0 at zero length).
      damp: ``(S,)`` ``e0 . dd``, the change of each spring along its frozen direction
        (m); ``None`` for an undamped scene.
    """

    e: jax.Array
    s: jax.Array
    dpsi: jax.Array
    along: jax.Array
    across: jax.Array
    damp: jax.Array | None


def spring_terms(w, p: StepProblem) -> SpringTerms:
    """:class:`SpringTerms` at the deviation ``w (N, 3)``."""
    # written once and read by every use (``_fusion``): the spring changes, and the
    # direction, stretch and force that the objective, the gradient and the force scale
    # each read at both ends of every spring
    dd = materialized(p.spring_change(w))
    s = p.s0 + en.stretch_increment(p.d0, p.l0, dd)
    k = p.cloth.stiffness
    e, dpsi, along, across = en.radial_parts(p.d0 + dd, s, k)
    e, s, dpsi = materialized(e), materialized(s), materialized(dpsi)
    return SpringTerms(e, s, dpsi, along, across, None if p.e0 is None else dot(p.e0, dd))


def objective(w, p: StepProblem, t: SpringTerms, parts: ContactParts | None = None):
    """``g(w)`` (J) from the spring terms ``t`` at ``w`` (and :func:`contact_parts` at ``w``
    when already computed)."""
    c = p.cloth
    g = 0.5 / p.h**2 * jnp.sum(c.mass[:, None] * w * w)  # inertia, with gravity's work
    g = g + jnp.sum(en.element_potential(t.s, c.stiffness, t.damp, p.d_over_h))
    if parts is not None:
        return g + parts.value
    if p.has_others:
        g = g + others(w, p)[0]
    return g


def incremental_potential(w, p: StepProblem):
    """``g(w)`` of the module doc (J), for a deviation ``w (N, 3)`` (m) from the prediction.

    The one definition of the step's objective: Newton's gradient and Hessian blocks are
    its derivatives in the radial form (:class:`SpringTerms`), tested equal to
    ``jax.grad`` and ``jax.hessian`` of this function.
    """
    return objective(w, p, spring_terms(w, p))


def start_objective(p: StepProblem):
    """``g(p.start)`` (J) without contact: at the lab's start (the displacement 0) every
    spring keeps its length ``l0`` and changes by 0 along ``e0``, so ``g`` is the inertia
    term of ``w = -y`` plus the springs' potential at their stretches ``s0``, with no pass
    over the particles' spring ends (tested equal to :func:`incremental_potential`)."""
    c = p.cloth
    y = p.prediction
    return 0.5 / p.h**2 * jnp.sum(c.mass[:, None] * y * y) + jnp.sum(en.spring_potential(p.s0, c.stiffness))


def gradient(w, p: StepProblem, t: SpringTerms, parts: ContactParts | None = None):
    """``grad g(w)`` ``(N, 3)`` (N) from the spring terms ``t`` at ``w``: inertia plus the
    per-spring forces ``psi'(s) e (+ (d/h)(e0 . dd) e0)`` summed at both ends (no
    scatter: ``_layout``), plus the contact terms' ``jax.grad`` (``parts``:
    :func:`contact_parts` at ``w`` when already computed)."""
    c = p.cloth
    f = t.dpsi[:, None] * t.e
    if t.damp is not None:
        f = f + (p.d_over_h * t.damp)[:, None] * p.e0
    out = c.mass[:, None] / p.h**2 * w + p.sum(materialized(f))
    parts = contact_parts(w, p) if parts is None else parts
    return out if parts is None else out + parts.grad


def force_scale(w, p: StepProblem, t: SpringTerms | None = None, parts: ContactParts | None = None):
    """``(N,)`` size of the terms that make up ``grad g`` at each particle (N).

    Inertia ``m/h^2 |u - h v^n|`` (``u - h v^n = w + h^2 g``) plus gravity ``m |g|`` plus
    the magnitudes of the spring (and damping) forces and of the contact forces acting on
    the particle.  The gradient is judged small relative to the largest of these, which is
    what float rounding can resolve.  ``t``, ``parts``: the spring terms and
    :func:`contact_parts` at ``w`` when already computed.
    """
    c = p.cloth
    t = spring_terms(w, p) if t is None else t
    f = jnp.abs(t.dpsi)
    if t.damp is not None:
        f = f + jnp.abs(p.d_over_h * t.damp)
    m = c.mass
    inertia = m / p.h**2 * en._length(w + p.h**2 * c.gravity)
    scale = inertia + m * en._length(c.gravity) + p.sum(materialized(f), signed=False)
    if parts is not None:
        return scale + parts.scale
    if p.has_others:
        scale = scale + others(w, p)[1]
    return scale


def relative_gradient(gvec, w, p: StepProblem, t: SpringTerms | None = None, parts: ContactParts | None = None):
    """``max_i |grad_i g| / max_i scale_i`` over free particles (dimensionless, never NaN)."""
    free = p.free[:, 0] > 0
    gmax = jnp.max(jnp.where(free, en._length(gvec), 0.0))
    smax = jnp.max(jnp.where(free, force_scale(w, p, t, parts), 0.0))
    rel = gmax / jnp.maximum(smax, tiny(w.dtype))
    return jnp.where(jnp.isnan(rel), jnp.inf, rel)


def condition_bound(p: StepProblem, t: SpringTerms):
    """``()`` an upper bound on the condition number of ``g``'s Hessian (springs and damping).

    Gershgorin's bound for the 3x3 block rows of ``M/h^2 + sum_s A_s`` with each spring
    block projected PSD: ``max_i (m_i/h^2 + 2 sum_{s at i} |A_s|) / min_i m_i/h^2``, over
    free particles, ``|A_s| <= max(psi'', psi'/l, 0) + d/h``.  Contact terms are left out.
    ``inf`` where the bound is not a number of at least 1 (invalid masses under ``jit``).
    """
    c = p.cloth
    a = jnp.maximum(jnp.maximum(t.along, t.across), 0.0)
    if t.damp is not None:
        a = a + p.d_over_h
    inertia = c.mass / p.h**2
    free = p.free[:, 0] > 0
    hi = jnp.max(jnp.where(free, inertia + 2.0 * p.sum(materialized(a), signed=False), 0.0))
    lo = jnp.min(jnp.where(free, inertia, jnp.inf))
    r = hi / lo
    return jnp.where(jnp.any(free), jnp.where(r >= 1.0, r, jnp.inf), 1.0)


def blocks(w, p: StepProblem, *, project_psd: bool, terms: SpringTerms | None = None):
    """``(S, 3, 3)`` Hessian blocks of the spring and damping terms of ``g`` at ``w``.

    ``terms``: :func:`spring_terms` at ``w`` when already computed (the exact and the
    projected blocks share them)."""
    t = spring_terms(w, p) if terms is None else terms
    doh = p.d_over_h if p.e0 is not None else None
    return en.radial_blocks(t.e, t.along, t.across, p.e0, doh, project_psd=project_psd)
