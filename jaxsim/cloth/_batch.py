"""Rollouts over many parameter sets of one scene layout: ``jax.vmap`` over scenes,
split across local devices with ``NamedSharding`` when there are several."""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp

from .. import _sharding
from ._integrators import ImplicitEuler
from ._scene import Cloth, State
from ._step import _rollout, check_inputs


def stack_scenes(scenes: Sequence[Cloth]) -> Cloth:
    """Stack validated scenes of the same layout into one batched ``Cloth``.

    Every array leaf gains a leading ``(B,)`` axis.  The scenes must have the same
    particle and spring counts and the same static ``damped`` flag.
    """
    scenes = list(scenes)
    if not scenes or not all(isinstance(s, Cloth) for s in scenes):
        raise TypeError("stack_scenes needs a non-empty sequence of jaxsim.cloth.Cloth")
    first = scenes[0]
    for s in scenes[1:]:
        if (s.num_particles, s.num_springs, s.damped, s.dtype) != (first.num_particles, first.num_springs, first.damped, first.dtype):
            raise ValueError("scenes differ in particle or spring count, dtype or damped flag; they cannot be batched")
    D = max(s.incidence.shape[1] for s in scenes)
    inc = [jnp.pad(s.incidence, ((0, 0), (0, D - s.incidence.shape[1]))) for s in scenes]
    leaves = {f: jnp.stack([getattr(s, f) for s in scenes]) for f in _LEAVES if f != "incidence"}
    return _unchecked(first, {**leaves, "incidence": jnp.stack(inc)})


_LEAVES = ("rest", "springs", "rest_length", "stiffness", "mass", "pinned", "gravity", "damping", "incidence")


def _unchecked(like: Cloth, leaves: dict) -> Cloth:
    """A ``Cloth`` with ``leaves`` and ``like``'s static flag, skipping the per-scene shape
    checks (batched leaves carry a leading scene axis)."""
    out = object.__new__(Cloth)
    for f in _LEAVES:
        object.__setattr__(out, f, leaves[f])
    object.__setattr__(out, "damped", like.damped)
    return out


@functools.partial(jax.jit, static_argnames=("n_steps", "integrator", "checkpoint", "state_batched"))
def _batched(scenes, state, dt, n_steps, integrator, checkpoint, state_batched):
    run = functools.partial(_rollout, dt=dt, n_steps=n_steps, integrator=integrator, checkpoint=checkpoint)
    return jax.vmap(lambda c, s: run(c, s), in_axes=(0, 0 if state_batched else None))(scenes, state)


def batch_rollout(scenes, state: State, dt, n_steps: int, integrator=ImplicitEuler(), *,
                  sharded: bool | None = None, checkpoint: bool = False):
    """``rollout`` for ``B`` parameter sets at once.

    Args:
      scenes: a sequence of ``Cloth`` with one layout, or a batched ``Cloth`` from
        :func:`stack_scenes`.
      state: one ``State`` for every scene, or a batched one (``x, v (B, N, 3)``).
      dt, n_steps, integrator, checkpoint: as for :func:`jaxsim.cloth.rollout`.
      sharded: split the ``B`` scenes across local devices (``None``: when there are
        several; see ``jaxsim._sharding``).

    Returns:
      ``(states, infos)`` with leading ``(B, n_steps)`` axes.
    """
    if not isinstance(scenes, Cloth):
        for s in scenes:
            check_inputs(s, state if state.x.ndim == 2 else State(state.x[0], state.v[0]), dt, integrator)
        scenes = stack_scenes(scenes)
    if scenes.rest.ndim != 3:
        raise ValueError("batch_rollout needs a batched Cloth (leaves with a leading scene axis); use stack_scenes")
    B = scenes.rest.shape[0]
    state_batched = state.x.ndim == 3
    if state_batched and state.x.shape[0] != B:
        raise ValueError(f"state has {state.x.shape[0]} entries for {B} scenes")
    if not (isinstance(n_steps, int) and n_steps >= 1):
        raise ValueError(f"n_steps must be an int >= 1, got {n_steps!r}")
    mesh = _sharding.batch_mesh(sharded, B)
    pad = 0
    if mesh is not None:
        leaves, pad = _sharding.shard_leading({f: getattr(scenes, f) for f in _LEAVES}, mesh, B)
        scenes = _unchecked(scenes, leaves)
        if state_batched:
            state, _ = _sharding.shard_leading(state, mesh, B)
    out = _batched(scenes, state, jnp.asarray(dt, scenes.dtype), n_steps, integrator, bool(checkpoint), state_batched)
    return _sharding.unpad(out, pad)
