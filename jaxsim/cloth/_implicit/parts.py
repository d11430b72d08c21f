"""The step's terms besides inertia and springs (colliders, self-contact, wind), from one pass.

``g``'s value, gradient and the force sizes of the stop test (``problem.force_scale``) all
read these terms; one ``jax.value_and_grad`` gives the three, so each self-contact pair's
distance is computed once per evaluation.  ``p`` is the step's ``problem.StepProblem``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..._dataclass import pytree_dataclass
from . import contact as ct
from .._model import aero as aero_
from .._self import terms as sc


@pytree_dataclass
class ContactParts:
    """The colliders', self-contact's and wind's terms of ``g`` at one ``w``, from one pass
    (:func:`contact_parts`).

    Attributes:
      value: ``()`` their potentials (J).
      grad: ``(N, 3)`` their gradient (N).
      scale: ``(N,)`` the sizes of their forces at each particle (N; ``problem.force_scale``).
    """

    value: jax.Array
    grad: jax.Array
    scale: jax.Array


def _contact_potential(w, p):
    return ct.potential(p.displacement(w), p.x0, p.cloth, p.contact, p.free)


def _aero_potential(w, p):
    return aero_.potential(p.aero, p.displacement(w), p.h)


def others(w, p, with_self=True):
    """``(value (J), force sizes (N,))`` of the colliders', self-contact's (unless not
    ``with_self``) and wind's terms."""
    c, v = p.cloth, jnp.zeros((), w.dtype)
    f = jnp.zeros((c.num_particles,), w.dtype)
    if p.contact is not None:
        v = v + _contact_potential(w, p)
        f = f + ct.force_magnitudes(p.displacement(w), p.x0, c, p.contact, p.free)
    if p.selfc is not None and with_self:
        e, fs = sc.potential_and_forces(p.selfc, p.positions(w), p.free)
        v, f = v + e, f + fs
    if p.aero is not None:
        v = v + _aero_potential(w, p)
        f = f + aero_.force_magnitudes(p.aero, p.displacement(w), p.h, c.num_particles)
    return v, f


def contact_parts(w, p) -> ContactParts | None:
    """:class:`ContactParts` at ``w (N, 3)``, or ``None`` for a scene with springs only.  One
    ``jax.value_and_grad``: the pairs' distances are computed once for the value, the
    gradient and the force sizes.  With a self-contact set in use (Newton's evaluations),
    its terms are summed over the slots in use only (``_self.terms.summed``; ``u`` is
    ``w`` plus a constant, so their gradient in ``x`` is the one in ``w``)."""
    if not p.has_others:
        return None
    in_use = p.selfc is not None and p.selfc.pairs is not None
    (v, f), g = jax.value_and_grad(others, has_aux=True)(w, p, not in_use)
    if in_use:
        e, gs, fs = sc.summed(p.selfc, p.positions(w), p.free)
        v, g, f = v + e, g + gs, f + fs
    return ContactParts(v, g, f)
