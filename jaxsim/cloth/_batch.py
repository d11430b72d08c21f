"""Rollouts over many parameter sets of one scene layout: ``jax.vmap`` over scenes,
split across local devices with ``NamedSharding`` when there are several."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp

import numpy as np

from .. import _sharding
from .._dataclass import is_concrete
from .._validate import check_bool, check_finite, check_int, check_positive, check_real
from ._model.colliders import SCENE_FIELDS, collider_kinds, count_inside, describe_inside
from ._integrators import BDF2, ExplicitEuler, ImplicitEuler
from ._layout import batch_layout
from ._model.scene import Cloth, State, frozen_ids
from ._checks import check_inputs, check_pins, check_resume
from ._step import _rollout


def stack_scenes(scenes: Sequence[Cloth]) -> Cloth:
    """Stack validated scenes of the same layout into one batched ``Cloth``.

    Every array leaf gains a leading ``(B,)`` axis, the colliders' leaves and the
    contact gap included.  The scenes must have the same particle and spring counts,
    the same static ``damped`` flag, and the same colliders in kind, order and friction
    on/off flag (their positions, sizes and coefficients may differ).
    """
    scenes = list(scenes)
    if not scenes or not all(isinstance(s, Cloth) for s in scenes):
        raise TypeError("stack_scenes needs a non-empty sequence of jaxsim.cloth.Cloth")
    first = scenes[0]
    for k, s in enumerate(scenes[1:], start=1):
        if s.rest.ndim != 2:
            raise ValueError(f"scenes[{k}] is already batched; stack unbatched scenes")
        if (s.num_particles, s.num_springs, s.damped, s.dtype) != (first.num_particles, first.num_springs, first.damped, first.dtype):
            raise ValueError("scenes differ in particle or spring count, dtype or damped flag; they cannot be batched")
        if collider_kinds(s.colliders) != collider_kinds(first.colliders):
            raise ValueError(f"scenes[{k}] has colliders {collider_kinds(s.colliders)}, scenes[0] has "
                             f"{collider_kinds(first.colliders)}: batched scenes need the same colliders in kind, "
                             "order and friction on/off (their values may differ)")
        if (s.contact_stiffness is None) != (first.contact_stiffness is None):
            raise ValueError("scenes differ in whether contact_stiffness is set; set it on all or none")
        if s.aero != first.aero:
            raise ValueError(f"scenes[{k}] differs from scenes[0] in whether drag or lift act (aero); batched scenes "
                             "need the same")
        if (s.self_contact, s.self_contact_pairs, np.shape(s.contact_faces)) != (
                first.self_contact, first.self_contact_pairs, np.shape(first.contact_faces)):
            raise ValueError(f"scenes[{k}] differs from scenes[0] in self_contact, self_contact_pairs or the number "
                             "of contact faces; batched scenes need the same")
    leaves = {f: jnp.stack([getattr(s, f) for s in scenes]) for f in _LEAVES if f != "springs"}
    leaves["springs"] = frozen_ids(np.stack([s.springs for s in scenes]))  # a topology: concrete under jit too
    leaves.update(_stack_contact(scenes))
    if first.wind is not None:
        for f in _AERO:
            leaves[f] = jnp.stack([jnp.zeros(np.shape(getattr(first, f)), first.dtype) if getattr(s, f) is None
                                   else getattr(s, f) for s in scenes])
    if first.contact_faces is not None:  # topologies, as the springs
        for f in _SELF:
            leaves[f] = frozen_ids(np.stack([getattr(s, f) for s in scenes]))
    return dataclasses.replace(first, **leaves)  # a batch: not checked again per scene (Cloth)


def _stack_contact(scenes) -> dict:
    """The contact leaves of ``scenes`` stacked on a leading ``(B,)`` axis."""
    stack = lambda *xs: jnp.stack(xs)  # noqa: E731
    out = {"colliders": jax.tree_util.tree_map(stack, *[s.colliders for s in scenes]),
           "contact_gap": jnp.stack([s.contact_gap for s in scenes]),
           "contact_stiffness": None}
    if scenes[0].contact_stiffness is not None:
        out["contact_stiffness"] = jnp.stack([s.contact_stiffness for s in scenes])
    return out


_LEAVES = ("rest", "springs", "rest_length", "stiffness", "mass", "pinned", "gravity", "damping")
#: The leaves that contact adds (a pytree of colliders, the gap, the barrier stiffness or ``None``).
_CONTACT = ("colliders", "contact_gap", "contact_stiffness")
#: The leaves that self-contact adds (``None`` without it).
_SELF = ("contact_faces", "contact_edges")
#: The leaves that the wind adds (``None`` without it).
_AERO = ("wind", "drag", "lift")


@functools.partial(jax.jit, static_argnames=("n_steps", "integrator", "checkpoint", "state_batched", "layout_batched",
                                             "pins_batched"))
def _batched(scenes, layout, state, dt, n_steps, integrator, checkpoint, state_batched, layout_batched, resume=None,
             pins=None, pins_batched=False):
    run = functools.partial(_rollout, dt=dt, n_steps=n_steps, integrator=integrator, checkpoint=checkpoint)
    return jax.vmap(lambda c, lay, s, r, p: run(c, lay, s, resume=r, pins=p),
                    in_axes=(0, 0 if layout_batched else None, 0 if state_batched else None, 0,
                             0 if pins_batched else None))(scenes, layout, state, resume, pins)


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
              "pinned": (B, N), "gravity": (B, 3), "damping": (B,)}
    for f, shape in shapes.items():
        a = np.asarray(getattr(scenes, f))
        if a.shape != shape:
            raise ValueError(f"batched scene field {f} must have shape {shape}, got {a.shape}")
        if f not in ("springs", "pinned"):
            check_finite(f"batched scene {f}", a)
    for f, strict in (("rest_length", True), ("mass", True), ("stiffness", False), ("damping", False)):
        check_positive(f"batched scene {f}", np.asarray(getattr(scenes, f)), strict=strict)
    springs = np.asarray(scenes.springs)
    if springs.size and (springs.min() < 0 or springs.max() >= N):
        raise ValueError(f"batched scene spring ids must lie in [0, {N}), got range [{springs.min()}, {springs.max()}]")
    check_batched_contact(scenes, B)


def check_batched_contact(scenes: Cloth, B: int) -> None:
    """The contact leaves of a batched scene: a leading ``(B,)`` axis on every one, and
    every free particle of every scene's rest shape outside its colliders."""
    if not is_concrete(*jax.tree_util.tree_leaves((scenes.colliders, scenes.contact_gap, scenes.contact_stiffness))):
        return
    for k, c in enumerate(scenes.colliders):
        for f in SCENE_FIELDS[type(c)]:
            a = np.asarray(getattr(c, f))
            if a.ndim < 1 or a.shape[0] != B:
                raise ValueError(f"batched scene colliders[{k}] ({type(c).__name__}) {f} needs a leading ({B},) "
                                 f"scene axis, got shape {a.shape}; use stack_scenes")
            check_finite(f"batched scene colliders[{k}] {f}", a)
    for f in ("contact_gap", "contact_stiffness"):
        a = getattr(scenes, f)
        if a is None and f == "contact_stiffness":
            continue
        if np.shape(a) != (B,):
            raise ValueError(f"batched scene {f} must have shape ({B},), got {np.shape(a)}; use stack_scenes")
        check_positive(f"batched scene {f}", check_finite(f"batched scene {f}", a))
    check_outside(scenes, scenes.rest, "rest positions")


def check_outside(scenes: Cloth, x, what: str) -> None:
    """Raise unless every free particle of ``x (B, N, 3)`` (or ``(N, 3)``, one for every
    scene) lies outside every scene's colliders (concrete inputs)."""
    if not scenes.colliders or not is_concrete(x, *jax.tree_util.tree_leaves(scenes.colliders)):
        return
    x = np.broadcast_to(np.asarray(x, np.float64), scenes.rest.shape)
    free = ~np.asarray(scenes.pinned)
    for b in range(x.shape[0]):
        inside = count_inside(jax.tree_util.tree_map(lambda a: np.asarray(a)[b], scenes.colliders), x[b], free[b])
        if inside:
            raise ValueError(f"scene {b}: " + describe_inside(inside, what))


def batch_rollout(scenes, state: State, dt, n_steps: int, integrator=ImplicitEuler(), *,
                  sharded: bool | None = None, checkpoint: bool = False, resume=None, pins=None):
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
      pins: moving pins as for ``rollout``: ``(n_steps, K, 3)`` for every scene, or
        ``(B, n_steps, K, 3)`` per scene (every scene with ``K`` pinned particles).

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
        # from the scenes' own arrays: under a jit around this call the stack is traced
        layout, layout_batched = batch_layout([s.springs for s in scenes], [s.rest for s in scenes])
        scenes = stack_scenes(scenes)
    else:
        layout, layout_batched = batch_layout(scenes.springs, scenes.rest)
    check_batched(scenes)
    if scenes.colliders and isinstance(integrator, ExplicitEuler):
        raise ValueError("colliders need ImplicitEuler: contact is a barrier in its incremental potential")
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
    check_outside(scenes, state.x, "state")
    if is_concrete(dt):
        check_real("dt", dt, minimum=0.0, strict=True)
    n_steps = check_int("n_steps", n_steps, 1)
    checkpoint = check_bool("checkpoint", checkpoint)
    resume = check_resume(scenes, resume, batch=B, bdf2=isinstance(integrator, BDF2))
    pins_batched = pins is not None and np.ndim(pins) == 4
    pins = check_pins(scenes, pins, ((B,) if pins_batched else ()) + (n_steps,), integrator)
    mesh = _sharding.batch_mesh(sharded, B)
    pad = 0
    if mesh is not None:
        names = (_LEAVES + _CONTACT + (_SELF if scenes.contact_faces is not None else ())
                 + (_AERO if scenes.wind is not None else ()))
        leaves, pad = _sharding.shard_leading({f: getattr(scenes, f) for f in names}, mesh, B)
        scenes = dataclasses.replace(scenes, **leaves)
        if layout_batched:
            layout, _ = _sharding.shard_leading(layout, mesh, B)
        if state_batched:
            state, _ = _sharding.shard_leading(state, mesh, B)
        if resume is not None:
            resume, _ = _sharding.shard_leading(resume, mesh, B)
        if pins_batched:
            pins, _ = _sharding.shard_leading(pins, mesh, B)
    out = _batched(scenes, layout, state, jnp.asarray(dt, scenes.dtype), n_steps, integrator, bool(checkpoint),
                   state_batched, layout_batched, resume, pins, pins_batched)
    return _sharding.unpad(out, pad)
