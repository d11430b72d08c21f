"""Explicit (symplectic) Euler substeps, with blow-up detection by energy growth."""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax

from ._model import energy as en
from ._integrators import ExplicitEuler
from ._layout import spring_diff, spring_sum
from ._model.scene import Cloth, State
from ._vec import dot

#: A substep is rejected as a blow-up when the total energy has risen, since the start of
#: the step, by more than ``GROWTH`` times the energy the scene could legitimately
#: exchange in it (kinetic plus spring energy at the start, plus the work of gravity).
#: Physically the total energy cannot rise at all (pins are fixed, damping dissipates);
#: a stable symplectic Euler run oscillates about it by a bounded factor, an unstable one
#: grows geometrically and crosses any such bound within a few substeps.
GROWTH = 100.0


def bounded(cloth: Cloth, x, v):
    """Finite, and not flown off to a distance no simulation of this scene reaches."""
    extent = jnp.max(jnp.abs(cloth.rest)) + 1.0
    return jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(v)) & (jnp.max(jnp.abs(x)) < 1e6 * extent)


def damping_forces(cloth: Cloth, x, v, layout=None):
    """Along-spring damping forces ``d ((v_j - v_i) . e) e`` (N), ``(N, 3)``."""
    e, _ = en.spring_directions(cloth, x, layout)
    f = cloth.damping * dot(spring_diff(cloth, v, layout), e)[:, None] * e
    return -spring_sum(cloth, f, layout=layout)  # +f on each spring's first particle, -f on its second


def explicit(cloth: Cloth, state: State, dt, integ: ExplicitEuler, layout=None):
    """``integ.substeps`` substeps ``v += h F/m``, ``x += h v``.

    Returns ``(state, ok)``: the state after the last substep that was finite, bounded
    and without energy blow-up (``GROWTH``), and whether every substep was.
    """
    h = dt / integ.substeps
    free = (~cloth.pinned)[:, None]
    eps = jnp.finfo(state.x.dtype).eps
    grav0 = en.gravity_energy(cloth, state.x)
    free_energy0 = en.kinetic_energy(cloth, state.v) + en.spring_energy(cloth, state.x, layout)
    e0 = free_energy0 + grav0

    def sub(c, _):
        x, v, ok = c
        F = en.forces(cloth, x, layout)  # springs + gravity, from jax.grad(energy)
        if cloth.damped:
            F = F + damping_forces(cloth, x, v, layout)
        v_new = jnp.where(free, v + h * F / cloth.mass[:, None], 0.0)
        x_new = x + h * v_new
        grav = en.gravity_energy(cloth, x_new)
        e = en.total_energy(cloth, x_new, v_new, layout)
        allowed = GROWTH * (free_energy0 + jnp.abs(grav - grav0)) + 64 * eps * (jnp.abs(e0) + free_energy0)
        good = ok & bounded(cloth, x_new, v_new) & (e - e0 <= allowed)
        return (jnp.where(good, x_new, x), jnp.where(good, v_new, v), good), None

    (x, v, ok), _ = lax.scan(sub, (state.x, state.v, jnp.array(True)), None, length=integ.substeps)
    return State(x, v), ok
