"""Time stepping: ``step`` and ``rollout`` for explicit and implicit Euler."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
from jax import lax

from .._validate import check_bool, check_int
from ._checks import check_inputs, check_path, check_pins, check_pins_outside, check_resume, check_wind, particle_array, \
    valid_inputs
from ._explicit import explicit
from ._implicit.bdf2 import Before
from ._implicit.extrapolate import History
from ._implicit.step import implicit
from ._implicit.substeps import Memory
from ._implicit import trbdf2
from ._info import StepInfo
from ._integrators import BDF2, TRBDF2, ExplicitEuler, ImplicitEuler
from ._layout import Layout, layout_of
from ._model.scene import Cloth, State

def _explicit(cloth: Cloth, state: State, dt, integ: ExplicitEuler, layout: Layout | None = None):
    valid = valid_inputs(cloth, dt)
    new, ok = explicit(cloth, state, dt, integ, layout)
    ok = ok & valid
    z = jnp.zeros((), state.x.dtype)
    info = StepInfo(newton_iters=jnp.int32(0), cg_iters=jnp.int32(0), grad_norm=z, rel_grad=z, step_size=z,
                    backtracks=jnp.int32(0), residual=z, converged=ok, stable=ok, valid=valid,
                    cond_bound=jnp.ones((), state.x.dtype), substeps=jnp.int32(integ.substeps))
    return State(jnp.where(valid, new.x, state.x), jnp.where(valid, new.v, state.v)), info


def pin_targets(cloth: Cloth, x, pins):
    """``(N, 3)`` ``x`` with the pinned rows set to ``pins (K, 3)`` (in the order of
    ``jnp.flatnonzero(cloth.pinned)``); ``None`` when ``pins`` is."""
    if pins is None:
        return None
    return x.at[jnp.flatnonzero(cloth.pinned, size=pins.shape[0])].set(pins)


@functools.partial(jax.jit, static_argnames=("integrator",))
def _step(cloth, layout, state, dt, integrator, prev=None, guess=None, history=None, before=None, pins=None,
          memory=None):
    """``(State, StepInfo, Before | None)``: one step on ``cloth`` with its ``layout``
    (``_layout.layout_of``); an implicit one may start Newton from ``guess`` (end-of-step
    positions, ``(N, 3)``) or from the extrapolation of a :class:`History`; ``before``:
    BDF2's memory (``_implicit.bdf2.Before``), TR-BDF2's (``_implicit.trbdf2.Stage``),
    or ``None``; ``pins``: ``(K, 3)``
    the pinned particles' positions at the end of the step, or ``None``; ``memory``: the
    adaptive substeps' memory (``StepInfo.memory`` of the step before), or ``None``."""
    if not cloth.aero and cloth.wind is not None:  # the step never reads them
        cloth = dataclasses.replace(cloth, wind=None, drag=None, lift=None)
    if isinstance(integrator, ExplicitEuler):
        return (*_explicit(cloth, state, dt, integrator, layout), None)
    if isinstance(integrator, TRBDF2):
        extrapolate = bool(integrator.extrapolate) and not cloth.colliders and not cloth.self_contact
        return trbdf2.step(cloth, state, dt, integrator, prev, layout, before, pin_targets(cloth, state.x, pins),
                           extrapolate, guess)
    start, tight = None, False
    if guess is not None:
        start = lambda p: (guess - p.x0) - p.prediction  # noqa: E731
    elif history is not None:
        start, tight = history.start, history.jerk
        if before is not None:  # BDF2's problem is not built on (x^n, v^n, h)
            start = lambda p: history.start_at(p, state.v)  # noqa: E731
    return implicit(cloth, state, dt, integrator, prev, start, tight, layout, before, pin_targets(cloth, state.x, pins),
                    memory)

def step(cloth: Cloth, state: State, dt, integrator=ImplicitEuler(), guess=None,
         previous: State | None = None, pins=None) -> tuple[State, StepInfo]:
    """Advance ``state`` by ``dt`` seconds.

    Args:
      cloth: the scene.
      state: ``State(x (N,3), v (N,3))``.
      dt: time step (s), > 0.
      integrator: ``ExplicitEuler(substeps)`` or ``ImplicitEuler(...)``.
      guess: ``(N, 3)`` predicted end-of-step positions (m), or ``None``.  Newton starts
        from it instead of ``x^n`` where the incremental potential is lower there (pinned
        rows ignored; not used with colliders or explicit Euler).  ``rollout`` passes
        ``x^n + h (2 v^n - v^{n-1})`` (``ImplicitEuler.extrapolate``); stepping by hand,
        ``guess=state.x + dt * (2 * state.v - previous.v)`` does the same.
      previous: ``BDF2`` only: the state ``dt`` before ``state``, or ``None`` (the step is
        then backward Euler, as a rollout's first).
      pins: ``(K, 3)`` where the scene's ``K`` pinned particles (in the order of
        ``jnp.flatnonzero(cloth.pinned)``) are at the end of the step (m), or ``None``.
        They move there in a straight line over the step (``ImplicitEuler`` or ``BDF2``).

    Returns:
      ``(new_state, StepInfo)`` in the scene's dtype (the state is cast to it).  Pinned
      particles keep their positions exactly, or end exactly on ``pins`` with the velocity
      of the step's motion there (``(pins - x) / dt`` for backward Euler).

    On Linux, call ``jaxsim.retain_host_memory()`` once when stepping large cloths one
    step per call: a float64 128x128 grid's step then stops faulting its 56 MB of scratch
    memory in again at every call (35.1 -> 20.1 ms per step, README "Compilation and memory").
    """
    state = check_inputs(cloth, state, dt, integrator)
    guess = None if guess is None else particle_array("guess", guess, cloth)
    dt = jnp.asarray(dt, cloth.dtype)
    before = None
    if previous is not None:
        if not isinstance(integrator, BDF2):
            raise ValueError(f"previous= is BDF2's (the state one step before); {type(integrator).__name__} "
                             "does not use it")
        if not isinstance(previous, State):
            raise TypeError(f"previous must be a jaxsim.cloth.State, got {type(previous).__name__}")
        px = particle_array("previous.x", previous.x, cloth)
        before = Before(px, particle_array("previous.v", previous.v, cloth), dt)
    elif isinstance(integrator, BDF2):
        before = Before.none(state.x, state.v)
    elif isinstance(integrator, TRBDF2):
        before = trbdf2.first(cloth, state.x, state.v)
    pins = check_pins(cloth, pins, (), integrator)
    new, info, _ = _step(cloth, layout_of(cloth.springs, cloth.rest), state, dt, integrator, guess=guess,
                         before=before, pins=pins)
    return new, info


@functools.partial(jax.jit, static_argnames=("n_steps", "integrator", "checkpoint"))
def _rollout(cloth, layout, state, dt, n_steps, integrator, checkpoint=False, path=None, resume=None, pins=None,
             wind=None):
    extrapolate = (isinstance(integrator, ImplicitEuler) and not isinstance(integrator, TRBDF2)
                   and integrator.extrapolate and not cloth.colliders and not cloth.self_contact)

    # adaptive substeps' memory: each step first attempts the level the step before left
    remember = (isinstance(integrator, ImplicitEuler) and not isinstance(integrator, TRBDF2)
                and integrator.max_substep_depth > 0)

    def f(carry, xs):
        cols, pin, air = xs
        s, prev, history, before, memory = carry  # history: None unless extrapolating; before: BDF2's
        scene = cloth if air is None else dataclasses.replace(cloth, wind=air)
        if cols is None:
            s2, info, before = _step(scene, layout, s, dt, integrator, history=history, before=before, pins=pin,
                                     memory=memory)
        else:  # a collider path: no extrapolation (colliders)
            s2, info, before = _step(dataclasses.replace(scene, colliders=cols), layout, s, dt, integrator, prev,
                                     before=before, pins=pin, memory=memory)
        history = None if history is None else history.advance(s.v, info, integrator.extrapolate)
        memory = info.memory if remember else None
        return (s2, cols if cols is not None else prev, history, before, memory), (s2, info)

    if checkpoint:
        f = jax.checkpoint(f, prevent_cse=False)
    prev0 = cloth.colliders if path is not None else None
    history = History.before(cloth, state.x, state.v, dt, integrator.extrapolate, resume, layout) if extrapolate else None
    before = None
    if isinstance(integrator, BDF2):
        before = Before.none(state.x, state.v) if resume is None else resume.before(state.x, state.v, dt)
    elif isinstance(integrator, TRBDF2):  # with resume too: the forces at the state (_implicit.trbdf2)
        before = trbdf2.first(cloth, state.x, state.v, layout)
    memory = None
    if remember:
        memory = Memory.start() if resume is None else resume.substep_memory(integrator.max_substep_depth)
    _, (states, infos) = lax.scan(f, (state, prev0, history, before, memory), (path, pins, wind), length=n_steps)
    return states, infos

def rollout(cloth: Cloth, state: State, dt, n_steps: int, integrator=ImplicitEuler(),
            checkpoint: bool = False, colliders=None, resume=None, pins=None, wind=None) -> tuple[State, StepInfo]:
    """``n_steps`` steps in one ``lax.scan``.

    Differentiable end to end: implicit steps carry implicit-function derivatives (one
    extra linear solve per step in reverse mode), explicit substeps are differentiated
    through the scan.  Implicit steps start Newton from ``x^n + h (2 v^n - v^{n-1})``
    (``ImplicitEuler.extrapolate``), or from the constant-jerk extrapolation
    (``extrapolate=2``; ``"auto"`` on the first step and after a step that converged
    within two iterations), where that lowers the incremental potential.  Before the
    first step ``v^{-1}`` and ``v^{-2}`` are those of the backward-Euler motion that ends
    at ``state`` (from its forces), so a smoothly moving cloth takes one Newton iteration
    from the first step on.

    Args:
      checkpoint: rematerialise each step in reverse mode (``jax.checkpoint``), so the
        backward pass keeps only the per-step states, ``O(T)`` of them, instead of every
        step's linearisation.  No effect on values or on forward evaluation.
      colliders: kinematic colliders, or ``None`` (static: the scene's).  A tuple like
        ``cloth.colliders`` whose leaves have a leading ``(n_steps,)`` axis: entry ``t`` is
        the colliders at the end of step ``t`` (the scene's are those at time 0).  A
        particle a collider sweeps over within a step starts that step's Newton solve
        pushed out to ``dhat / 2`` (``_implicit.contact``).
      resume: the previous rollout's ``(states, infos)``, ``state`` normally its last state
        (``State(states.x[-1], states.v[-1])``; the start is a guess, taken only where it
        lowers the incremental potential): the extrapolated start goes on from its
        velocities and from its last step's diagnostics (``"auto"``), so rollouts run in
        chunks start each step exactly as one long rollout would; the adaptive substeps'
        memory (``StepInfo.memory``) goes on too, so each chunk's first step attempts the
        level a long rollout's would.  Without it the
        velocities before come from the forces at ``state``, which differ from the
        previous rollout's only through damping's frozen directions (and ``"auto"``
        takes the motion as smooth).  No effect where ``rollout`` does not extrapolate
        (explicit Euler, ``extrapolate=0``, colliders), except with ``BDF2``: its memory
        goes on from the previous rollout's last step (taken as a step of ``dt``) where
        that step was taken whole, so chunks equal one long rollout; after a last step
        taken in substeps (or a one-step rollout) the first step is backward Euler
        (``_implicit.resume.Resume.before``).
      pins: ``(n_steps, K, 3)`` moving pins, or ``None``: entry ``t`` is where the scene's
        ``K`` pinned particles (in the order of ``jnp.flatnonzero(cloth.pinned)``) are at the
        end of step ``t`` (m).  They move on straight lines within a step (substeps
        included) and end each step exactly on the path; the free particles are solved with
        them as boundary conditions, and derivatives flow to the path (``ImplicitEuler`` or
        ``BDF2``; ``anim.bone_points`` gives such paths from a clip).
      wind: ``(n_steps, 3)`` the air's velocity over each step (m/s), or ``None`` (the
        scene's ``wind`` throughout); for a scene with ``drag`` or ``lift``.

    Returns:
      ``(states, infos)`` stacked over a leading ``(n_steps,)`` axis (``states.x`` is
      ``(n_steps, N, 3)``; the initial state is not included).
    """
    state = check_inputs(cloth, state, dt, integrator)
    n_steps = check_int("n_steps", n_steps, 1)
    path = check_path(cloth, colliders, n_steps)
    resume = check_resume(cloth, resume, bdf2=isinstance(integrator, BDF2))
    pins = check_pins(cloth, pins, (n_steps,), integrator)
    check_pins_outside(cloth, pins, path)
    wind = check_wind(cloth, wind, (n_steps,))
    layout = layout_of(cloth.springs, cloth.rest)
    return _rollout(cloth, layout, state, jnp.asarray(dt, cloth.dtype), n_steps, integrator,
                    check_bool("checkpoint", checkpoint), path, resume, pins, wind)
