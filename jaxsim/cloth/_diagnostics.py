"""Energy bookkeeping for rollouts: stability and per-step energy rises."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._dataclass import pytree_dataclass
from ._model.energy import total_energy
from ._model.scene import Cloth, State


@pytree_dataclass
class EnergyReport:
    """Energy history of a rollout.

    Attributes:
      energy: ``(T+1,)`` total energy (J) at the initial state and after each step.
      finite: ``()`` every state finite.
      stable: ``()`` every step's ``StepInfo.stable`` (no rejected step).
      rises: ``()`` int, number of steps whose energy rose.
      max_rise: ``()`` largest single-step rise (J), 0 if none.
      net_change: ``()`` final minus initial energy (J).
    """

    energy: jax.Array
    finite: jax.Array
    stable: jax.Array
    rises: jax.Array
    max_rise: jax.Array
    net_change: jax.Array


def energy_report(cloth: Cloth, state0: State, states: State, infos) -> EnergyReport:
    """Summarise the energy of ``rollout`` output ``(states, infos)`` started at ``state0``.

    Raises:
      ValueError: when ``state0`` is not ``(N, 3)`` or ``states`` not ``(T, N, 3)`` for the
        scene's ``N`` particles, or ``infos`` does not hold ``T`` steps (states from another
        scene or rollout).
    """
    if not isinstance(cloth, Cloth):
        raise TypeError(f"cloth must be a jaxsim.cloth.Cloth, got {type(cloth).__name__}")
    N = cloth.num_particles
    for name, st, shape in (("state0", state0, (N, 3)), ("states", states, (None, N, 3))):
        for field in ("x", "v"):
            got = tuple(jnp.shape(getattr(st, field, None)))
            if len(got) != len(shape) or any(w is not None and g != w for g, w in zip(got, shape)):
                want = "(" + ", ".join("T" if s is None else str(s) for s in shape) + ")"
                raise ValueError(f"energy_report: {name}.{field} must be {want} for this scene's {N} particles, got "
                                 f"{got} (states of another scene?)")
    T = jnp.shape(states.x)[0]
    if tuple(jnp.shape(infos.stable)) != (T,):
        raise ValueError(f"energy_report: infos must hold the rollout's {T} steps, got stable of shape "
                         f"{tuple(jnp.shape(infos.stable))}")
    e = jax.vmap(lambda x, v: total_energy(cloth, x, v))(states.x, states.v)
    e = jnp.concatenate([total_energy(cloth, state0.x, state0.v)[None], e])
    d = jnp.diff(e)
    return EnergyReport(
        energy=e,
        finite=jnp.all(jnp.isfinite(states.x)) & jnp.all(jnp.isfinite(states.v)),
        stable=jnp.all(infos.stable),
        rises=jnp.sum(d > 0),
        max_rise=jnp.maximum(jnp.max(d), 0.0),
        net_change=e[-1] - e[0],
    )
