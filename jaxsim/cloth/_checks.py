"""Boundary validation of ``step``, ``rollout`` and ``batch_rollout`` inputs, and the
same checks as a traced flag for inputs only known inside ``jit``."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._dataclass import is_concrete
from .._validate import check_finite, check_real, check_shape
from ._implicit.resume import Resume
from ._info import StepInfo
from ._integrators import BDF2, TRBDF2, ExplicitEuler, ImplicitEuler
from ._model.colliders import COLLIDERS, collider_kinds, count_inside, describe_inside, host_distance
from ._model.scene import Cloth, State
from ._self.intersect import first_intersection


def valid_inputs(cloth: Cloth, dt):
    """The boundary checks as a traced flag (for inputs only known inside ``jit``)."""
    leaves = (cloth.rest, cloth.rest_length, cloth.stiffness, cloth.mass, cloth.gravity, dt)
    finite = [jnp.all(jnp.isfinite(a)) for a in leaves]
    positive = [dt > 0, jnp.all(cloth.mass > 0), jnp.all(cloth.rest_length > 0), jnp.all(cloth.stiffness >= 0)]
    if cloth.damped:  # an undamped scene's compiled step never reads its damping leaf
        finite.append(jnp.isfinite(cloth.damping))
        positive.append(cloth.damping >= 0)
    return functools.reduce(jnp.logical_and, finite + positive)


def check_inputs(cloth: Cloth, state: State, dt, integrator) -> State:
    """Boundary validation (raises ``ValueError``/``TypeError`` before any tracing).

    Returns the state cast to the scene's dtype: the scene fixes the precision of the
    step, so a float64 state on a float32 scene is rounded and a float16 or integer
    state is widened.
    """
    if not isinstance(cloth, Cloth):
        raise TypeError(f"cloth must be a jaxsim.cloth.Cloth, got {type(cloth).__name__}")
    if not isinstance(state, State):
        raise TypeError(f"state must be a jaxsim.cloth.State, got {type(state).__name__}")
    if not isinstance(integrator, (ExplicitEuler, ImplicitEuler)):
        raise TypeError(f"integrator must be ExplicitEuler or ImplicitEuler, got {type(integrator).__name__}")
    if cloth.rest.ndim != 2:
        raise ValueError("this scene is batched (from stack_scenes): use batch_rollout")
    if cloth.colliders and isinstance(integrator, ExplicitEuler):
        raise ValueError("colliders need ImplicitEuler: contact is a barrier in its incremental potential")
    if cloth.self_contact and isinstance(integrator, ExplicitEuler):
        raise ValueError("self_contact needs ImplicitEuler: self-contact is a barrier in its incremental potential")
    if cloth.aero and isinstance(integrator, ExplicitEuler):
        raise ValueError("drag and lift need ImplicitEuler, BDF2 or TRBDF2: the wind is a term of their incremental potential")
    if cloth.self_contact and isinstance(integrator, (BDF2, TRBDF2)):
        raise ValueError(f"self_contact is not supported with {type(integrator).__name__} yet (its shifted base may "
                         "cross a surface); use ImplicitEuler")
    out = [particle_array(name, a, cloth) for name, a in (("state.x", state.x), ("state.v", state.v))]
    if cloth.self_contact and is_concrete(state.x):
        hit = first_intersection(np.asarray(out[0], np.float64), cloth.contact_faces, cloth.contact_edges)
        if hit is not None:
            raise ValueError(f"the state intersects itself: {hit}")
    if cloth.colliders and is_concrete(state.x) and is_concrete(*jax.tree_util.tree_leaves(cloth.colliders)):
        inside = count_inside(cloth.colliders, out[0], ~np.asarray(cloth.pinned))
        if inside:
            raise ValueError(describe_inside(inside, "state"))
    if is_concrete(dt):
        if np.ndim(dt) != 0:
            raise ValueError(f"dt must be a scalar, got shape {np.shape(dt)}")
        check_real("dt", dt, minimum=0.0, strict=True)
    return State(*out)


def particle_array(name: str, a, cloth: Cloth) -> jax.Array:
    """``a`` checked to be ``(N, 3)`` real and finite (finite where concrete), in the scene's dtype."""
    N = cloth.num_particles
    if is_concrete(a):
        a = check_finite(name, check_shape(name, a, (N, 3)))
        if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
            raise ValueError(f"{name} must hold real numbers, got dtype {a.dtype}")
    elif tuple(a.shape) != (N, 3):
        raise ValueError(f"{name} must have shape ({N}, 3), got {tuple(a.shape)}")
    return jnp.asarray(a, cloth.dtype)


def check_path(cloth: Cloth, colliders, n_steps: int):
    """A kinematic collider path: ``cloth.colliders``' structure with a leading ``(T,)`` axis."""
    if colliders is None:
        return None
    if not cloth.colliders:
        raise ValueError("a collider path needs a scene with colliders (cloth.replace(scene, colliders=...))")
    if isinstance(colliders, COLLIDERS):
        colliders = (colliders,)  # one collider, as the scene accepts it
    if not isinstance(colliders, (tuple, list)) or not all(isinstance(c, COLLIDERS) for c in colliders):
        raise ValueError("colliders (the path) must be a tuple of cloth.Plane, cloth.Sphere or cloth.Capsule like "
                         f"the scene's, with a leading (n_steps,) axis on every leaf; got {colliders!r:.200}")
    if collider_kinds(colliders) != collider_kinds(cloth.colliders):
        raise ValueError(f"colliders (the path) are {collider_kinds(colliders)}, the scene's are "
                         f"{collider_kinds(cloth.colliders)}: a path needs the same kinds, order and friction on/off "
                         "flags (a path with friction needs a scene collider with friction, and vice versa)")
    want = jax.tree_util.tree_structure(cloth.colliders)
    got = jax.tree_util.tree_structure(tuple(colliders))
    if got != want:
        raise ValueError("colliders (the path) must have the structure of the scene's colliders, with the same "
                         f"kinds and friction on/off flags: expected {want}, got {got}")
    leaves = []
    for a, ref in zip(jax.tree_util.tree_leaves(tuple(colliders)), jax.tree_util.tree_leaves(cloth.colliders)):
        shape = (n_steps,) + tuple(jnp.shape(ref))
        if tuple(jnp.shape(a)) != shape:
            raise ValueError(f"every leaf of the collider path needs shape {shape} (n_steps first), got {jnp.shape(a)}")
        if is_concrete(a):
            check_finite("collider path", a)
        leaves.append(jnp.asarray(a, cloth.dtype))
    return jax.tree_util.tree_unflatten(want, leaves)


def check_pins(cloth: Cloth, pins, lead: tuple, integrator):
    """Moving pins: ``pins`` of shape ``lead + (K, 3)``, ``K`` the scene's pinned particles
    (in the order of ``jnp.flatnonzero(cloth.pinned)``), finite, in the scene's dtype; or
    ``None``."""
    if pins is None:
        return None
    if isinstance(integrator, ExplicitEuler):
        raise ValueError("pins= needs ImplicitEuler, BDF2 or TRBDF2: explicit Euler's pins stay where they are")
    pinned = cloth.pinned
    K = int(np.sum(np.asarray(pinned), axis=-1).max()) if is_concrete(pinned) else None
    if K == 0:
        raise ValueError("pins= moves the scene's pinned particles, and this scene has none (pin them with "
                         "grid(..., pins=), from_mesh(..., pins=) or replace(scene, pinned=))")
    if is_concrete(pinned) and np.ndim(pinned) == 2:
        counts = np.sum(np.asarray(pinned), axis=-1)
        if np.any(counts != K):
            raise ValueError(f"pins= needs the same number of pinned particles in every scene, got {counts.tolist()}")
    shape = tuple(jnp.shape(pins))
    want = lead + (K, 3)
    if len(shape) != len(want) or any(w is not None and w != g for w, g in zip(want, shape)):
        names = ", ".join(str(d) for d in lead + ("K" if K is None else K, 3))
        raise ValueError(f"pins must have shape ({names}): the positions of the scene's {K} pinned particles "
                         f"(in the order of jnp.flatnonzero(scene.pinned)) at the end of each step, got {shape}")
    if is_concrete(pins):
        a = np.asarray(pins)
        if not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
            raise ValueError(f"pins must hold real numbers, got dtype {a.dtype}")
        check_finite("pins", a)
    return jnp.asarray(pins, cloth.dtype)


def check_pins_outside(cloth: Cloth, pins, path) -> None:
    """Concrete moving pins must stay outside every collider (the scene's, or the step's
    pose of a collider ``path``): a pinned particle is driven, not pushed back by the
    barrier, so a pin inside a body would leave the steps converged and stable around a
    cloth that passes through it.  ``ValueError`` naming the first step, pin and collider."""
    if pins is None or not cloth.colliders or np.ndim(cloth.pinned) != 1:
        return
    cols = cloth.colliders if path is None else path
    if not is_concrete(pins, *jax.tree_util.tree_leaves(cols)):
        return
    P = np.asarray(pins, np.float64)  # (T, K, 3)
    for k, c in enumerate(cols):
        if path is None:
            d = host_distance(c, P.reshape(-1, 3)).reshape(P.shape[:2])
        else:
            d = np.stack([host_distance(jax.tree_util.tree_map(lambda a, t=t: a[t], c), P[t]) for t in range(len(P))])
        bad = np.argwhere(d <= 0)
        if bad.size:
            t, p = bad[0]
            raise ValueError(f"pins: pinned particle {int(np.flatnonzero(np.asarray(cloth.pinned))[p])} is driven inside "
                             f"colliders[{k}] ({type(c).__name__}) at step {t} ({len(bad)} pin positions inside in "
                             "all); keep the pin path outside the colliders (a pin is not pushed back by contact)")


def check_wind(cloth: Cloth, wind, lead: tuple):
    """A per-step wind: ``lead + (3,)`` finite velocities (m/s) in the scene's dtype, for a
    scene with ``drag`` or ``lift``; or ``None``."""
    if wind is None:
        return None
    if not cloth.aero:
        raise ValueError("a wind path needs a scene with drag or lift (cloth.replace(scene, drag=...) on a scene "
                         "with triangles, or grid/from_mesh(..., drag=...))")
    if tuple(jnp.shape(wind)) != lead + (3,):
        raise ValueError(f"wind (the path) must have shape {lead + (3,)}, one velocity per step, "
                         f"got {tuple(jnp.shape(wind))}")
    if is_concrete(wind):
        check_finite("wind", wind)
    return jnp.asarray(wind, cloth.dtype)


def check_resume(cloth: Cloth, resume, batch: int | None = None, bdf2: bool = False):
    """The :class:`_implicit.resume.Resume` of a previous rollout's ``(states, infos)``,
    or ``None``.  ``batch``: ``B``, a previous ``batch_rollout``'s outputs (every shape
    with a leading ``(B,)`` axis); ``bdf2``: the rollout is BDF2's, which also reads the
    state one step before the last."""
    if resume is None:
        return None
    what = "batch_rollout" if batch else "rollout"
    if not (isinstance(resume, tuple) and len(resume) == 2 and isinstance(resume[0], State)
            and isinstance(resume[1], StepInfo)):
        raise TypeError(f"resume must be a previous {what}'s (states, infos)")
    states, infos = resume
    v = jnp.asarray(states.v)
    lead = () if batch is None else (batch,)
    k = len(lead)
    N = cloth.rest.shape[-2]
    if v.ndim != 3 + k or v.shape[:k] != lead or v.shape[k + 1:] != (N, 3) or v.shape[k] < 1:
        want = ", ".join(map(str, lead + ("T", N, 3)))
        raise ValueError(f"resume's states must have velocities of shape ({want}) (a {what}'s), got {v.shape}")
    T = v.shape[k]
    if jnp.shape(infos.converged) != lead + (T,) or jnp.shape(infos.newton_iters) != lead + (T,):
        raise ValueError(f"resume's infos must have a leading {lead + (T,)} axis like its states")
    if is_concrete(v):
        check_finite("resume's states.v", v)
    x_prev = whole = None
    if bdf2 and T >= 2:
        x = jnp.asarray(states.x)
        if x.shape != v.shape:
            raise ValueError(f"resume's states must have positions of shape {v.shape} like its velocities, got {x.shape}")
        if is_concrete(x):
            check_finite("resume's states.x", x)
        if jnp.shape(infos.substeps) != lead + (T,):
            raise ValueError(f"resume's infos.substeps must have a leading {lead + (T,)} axis like its states")
        x_prev = x[..., -2, :, :].astype(cloth.dtype)
        whole = jnp.asarray(infos.substeps[..., -1]) == 1
    memory = None
    if infos.memory is not None:
        if any(jnp.shape(m) != lead + (T,) for m in jax.tree_util.tree_leaves(infos.memory)):
            raise ValueError(f"resume's infos.memory must have a leading {lead + (T,)} axis like its states")
        memory = jax.tree_util.tree_map(lambda m: jnp.asarray(m[..., -1]), infos.memory)
    return Resume(v[..., -3:, :, :].astype(cloth.dtype), jnp.asarray(infos.converged[..., -1]),
                  jnp.asarray(infos.newton_iters[..., -1]), x_prev, whole, memory)
