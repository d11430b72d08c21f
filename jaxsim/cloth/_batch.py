"""Rollouts over many parameter sets of one scene layout: ``jax.vmap`` over scenes,
split across local devices with ``NamedSharding`` when there are several."""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp

import numpy as np

from .. import _sharding
from .._dataclass import is_concrete
from .._validate import check_bool, check_finite, check_int, check_positive, check_real
from ._coarse import block_ids
from ._integrators import ExplicitEuler, ImplicitEuler
from ._scene import Cloth, State
from ._step import _rollout, check_inputs, check_resume


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
    leaves = {f: jnp.stack([getattr(s, f) for s in scenes]) for f in _LEAVES if f not in ("incidence", "aggregates")}
    # any partition of the particles gives a valid preconditioner: the first scene's serves all
    leaves["aggregates"] = jnp.stack([first.aggregates] * len(scenes))
    # the grid operator when every scene has the same grid layout, else the general one
    stencil = first.stencil if all(s.stencil == first.stencil for s in scenes) else None
    return _unchecked(first, {**leaves, "incidence": jnp.stack(inc)}, stencil)


_LEAVES = ("rest", "springs", "rest_length", "stiffness", "mass", "pinned", "gravity", "damping", "incidence",
           "aggregates")


def _unchecked(like: Cloth, leaves: dict, stencil=None) -> Cloth:
    """A ``Cloth`` with ``leaves`` and ``like``'s static flag, skipping the per-scene shape
    checks (batched leaves carry a leading scene axis)."""
    out = object.__new__(Cloth)
    for f in _LEAVES:
        object.__setattr__(out, f, leaves[f])
    object.__setattr__(out, "damped", like.damped)
    object.__setattr__(out, "num_aggregates", like.num_aggregates)
    object.__setattr__(out, "stencil", stencil)
    object.__setattr__(out, "coarse_block", like.coarse_block if stencil is not None else 0)
    return out


@functools.partial(jax.jit, static_argnames=("n_steps", "integrator", "checkpoint", "state_batched"))
def _batched(scenes, state, dt, n_steps, integrator, checkpoint, state_batched, resume=None):
    run = functools.partial(_rollout, dt=dt, n_steps=n_steps, integrator=integrator, checkpoint=checkpoint)
    return jax.vmap(lambda c, s, r: run(c, s, resume=r),
                    in_axes=(0, 0 if state_batched else None, 0))(scenes, state, resume)


def check_batched(scenes: Cloth) -> None:
    """The ``Cloth`` checks on a batched scene from :func:`stack_scenes` (concrete leaves)."""
    if scenes.rest.ndim != 3:
        raise ValueError("batch_rollout needs a batched Cloth (leaves with a leading scene axis); use stack_scenes")
    leaves = [getattr(scenes, f) for f in _LEAVES]
    if not is_concrete(*leaves):
        return
    B, N, _ = scenes.rest.shape
    S = scenes.springs.shape[1]
    shapes = {"rest": (B, N, 3), "springs": (B, S, 2), "rest_length": (B, S), "stiffness": (B, S), "mass": (B, N),
              "pinned": (B, N), "gravity": (B, 3), "damping": (B,), "aggregates": (B, N)}
    for f, shape in shapes.items():
        a = np.asarray(getattr(scenes, f))
        if a.shape != shape:
            raise ValueError(f"batched scene field {f} must have shape {shape}, got {a.shape}")
        if f == "aggregates" and (a.min() < 0 or a.max() >= scenes.num_aggregates):
            raise ValueError(f"batched scene aggregates must lie in [0, {scenes.num_aggregates})")
        if f == "aggregates" and scenes.coarse_block and scenes.stencil is not None and not np.array_equal(
                a, np.broadcast_to(block_ids(scenes.stencil.rows, scenes.stencil.cols, scenes.coarse_block), a.shape)):
            raise ValueError("batched scene aggregates must be the grid's blocks (coarse_block); use stack_scenes")
        if f not in ("springs", "pinned", "aggregates"):
            check_finite(f"batched scene {f}", a)
    for f, strict in (("rest_length", True), ("mass", True), ("stiffness", False), ("damping", False)):
        check_positive(f"batched scene {f}", np.asarray(getattr(scenes, f)), strict=strict)
    springs = np.asarray(scenes.springs)
    if springs.size and (springs.min() < 0 or springs.max() >= N):
        raise ValueError(f"batched scene spring ids must lie in [0, {N}), got range [{springs.min()}, {springs.max()}]")


def batch_rollout(scenes, state: State, dt, n_steps: int, integrator=ImplicitEuler(), *,
                  sharded: bool | None = None, checkpoint: bool = False, resume=None):
    """``rollout`` for ``B`` parameter sets at once.

    Args:
      scenes: a sequence of ``Cloth`` with one layout, or a batched ``Cloth`` from
        :func:`stack_scenes`.
      state: one ``State`` for every scene, or a batched one (``x, v (B, N, 3)``).
      dt, n_steps, integrator, checkpoint: as for :func:`jaxsim.cloth.rollout`.
      sharded: split the ``B`` scenes across local devices (``None``: when there are
        several; see ``jaxsim._sharding``).
      resume: the previous ``batch_rollout``'s ``(states, infos)`` (leading ``(B, T)``
        axes), ``state`` normally its last states: each scene's extrapolated start goes on
        from its velocities, as ``rollout``'s ``resume`` does.

    Returns:
      ``(states, infos)`` with leading ``(B, n_steps)`` axes.
    """
    if not isinstance(state, State):
        raise TypeError(f"state must be a jaxsim.cloth.State, got {type(state).__name__}")
    if not isinstance(integrator, (ExplicitEuler, ImplicitEuler)):
        raise TypeError(f"integrator must be ExplicitEuler or ImplicitEuler, got {type(integrator).__name__}")
    if not isinstance(scenes, Cloth):
        scenes = list(scenes)
        for s in scenes:
            check_inputs(s, state if np.ndim(state.x) == 2 else State(state.x[0], state.v[0]), dt, integrator)
        scenes = stack_scenes(scenes)
    check_batched(scenes)
    B, N = scenes.rest.shape[0], scenes.rest.shape[1]
    state_batched = np.ndim(state.x) == 3
    want = (B, N, 3) if state_batched else (N, 3)
    for name, a in (("state.x", state.x), ("state.v", state.v)):
        if tuple(np.shape(a)) != want:
            raise ValueError(f"{name} must have shape {want} (or ({N}, 3) for all scenes) for {B} scenes of {N} "
                             f"particles, got {tuple(np.shape(a))}")
        if is_concrete(a):
            check_finite(name, a)
    state = State(jnp.asarray(state.x, scenes.dtype), jnp.asarray(state.v, scenes.dtype))
    if is_concrete(dt):
        check_real("dt", dt, minimum=0.0, strict=True)
    n_steps = check_int("n_steps", n_steps, 1)
    checkpoint = check_bool("checkpoint", checkpoint)
    resume = check_resume(scenes, resume, batch=B)
    mesh = _sharding.batch_mesh(sharded, B)
    pad = 0
    if mesh is not None:
        leaves, pad = _sharding.shard_leading({f: getattr(scenes, f) for f in _LEAVES}, mesh, B)
        scenes = _unchecked(scenes, leaves, scenes.stencil)
        if state_batched:
            state, _ = _sharding.shard_leading(state, mesh, B)
        if resume is not None:
            resume, _ = _sharding.shard_leading(resume, mesh, B)
    out = _batched(scenes, state, jnp.asarray(dt, scenes.dtype), n_steps, integrator, bool(checkpoint), state_batched,
                   resume)
    return _sharding.unpad(out, pad)
