"""Time stepping: ``step`` and ``rollout`` for explicit and implicit Euler."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._dataclass import is_concrete, pytree_dataclass
from .._validate import check_bool, check_finite, check_int, check_real, check_shape
from ._implicit import problem as pr
from ._explicit import bounded, explicit
from ._implicit.extrapolate import History
from ._implicit.implicit_diff import solution
from ._integrators import ExplicitEuler, ImplicitEuler
from ._implicit.newton import newton
from ._model.colliders import COLLIDERS, collider_kinds, count_inside, describe_inside
from ._layout import Layout, layout_of
from ._model.scene import Cloth, State
from ._implicit.trace import NewtonTrace


@pytree_dataclass
class StepInfo:
    """Diagnostics of one step (a leading ``T`` axis after ``rollout``).

    Attributes:
      newton_iters: Newton iterations taken (0 for explicit Euler).
      cg_iters: PCG iterations summed over the Newton iterations (0 unless CG).
      grad_norm: ``|grad g|`` over free particles at the returned positions (N).
      rel_grad: ``max_i |grad_i g| / max_i scale_i``, the gradient relative to the size
        of the terms it sums (inertia ``m/h^2 |x - y|``, gravity, spring and damping
        forces); 0 for explicit Euler.
      step_size: line-search step ``alpha`` of the last Newton iteration (0 when the start
        already met the gradient test and no iteration ran).
      backtracks: line-search halvings summed over the Newton iterations.
      residual: relative linear-solve residual of the last Newton iteration (``inf`` if
        the solve broke down; 0 when no iteration ran).
      converged: implicit: ``rel_grad <= rtol`` at the returned positions (the step
        solves backward Euler to that accuracy); explicit: same as ``stable``.
      stable: the step was taken: its inputs were valid, and the new state is finite,
        bounded and (explicit) without energy blow-up.  When False the returned state
        is the step's input (explicit: the last good substep), never NaN.
      valid: the scene and ``dt`` satisfied the boundary checks (finite, ``dt > 0``,
        masses and rest lengths ``> 0``, stiffness and damping ``>= 0``).  Only traced
        inputs can fail it, since concrete ones are checked before tracing; an invalid
        step is not taken.
      cond_bound: implicit: an upper bound on the condition number of the step's
        Hessian (springs and damping, ``_implicit.problem.condition_bound``) at the returned
        positions; explicit: 1.  The derivative of an implicit step (the implicit
        function theorem's linear solve) is reliable only while ``cond_bound *
        finfo(dtype).eps < 1``: beyond, the linear system is singular to the dtype's
        precision (float32 on the lab cloth somewhere between ``k h^2 / m`` = 3e4, where
        ``cond_bound * eps`` = 0.04, and 3e6, where it is 4), even when ``converged``.
      trace: ``NewtonTrace`` of the step's Newton iterations with
        ``ImplicitEuler(trace=True)``, else ``None``.
    """

    newton_iters: jax.Array
    cg_iters: jax.Array
    grad_norm: jax.Array
    rel_grad: jax.Array
    step_size: jax.Array
    backtracks: jax.Array
    residual: jax.Array
    converged: jax.Array
    stable: jax.Array
    valid: jax.Array
    cond_bound: jax.Array
    trace: NewtonTrace | None = None


def valid_inputs(cloth: Cloth, dt):
    """The boundary checks as a traced flag (for inputs only known inside ``jit``)."""
    leaves = (cloth.rest, cloth.rest_length, cloth.stiffness, cloth.mass, cloth.gravity, dt)
    finite = [jnp.all(jnp.isfinite(a)) for a in leaves]
    positive = [dt > 0, jnp.all(cloth.mass > 0), jnp.all(cloth.rest_length > 0), jnp.all(cloth.stiffness >= 0)]
    if cloth.damped:  # an undamped scene's compiled step never reads its damping leaf
        finite.append(jnp.isfinite(cloth.damping))
        positive.append(cloth.damping >= 0)
    return functools.reduce(jnp.logical_and, finite + positive)


def _explicit(cloth: Cloth, state: State, dt, integ: ExplicitEuler, layout: Layout | None = None):
    valid = valid_inputs(cloth, dt)
    new, ok = explicit(cloth, state, dt, integ, layout)
    ok = ok & valid
    z = jnp.zeros((), state.x.dtype)
    info = StepInfo(newton_iters=jnp.int32(0), cg_iters=jnp.int32(0), grad_norm=z, rel_grad=z, step_size=z,
                    backtracks=jnp.int32(0), residual=z, converged=ok, stable=ok, valid=valid,
                    cond_bound=jnp.ones((), state.x.dtype))
    return State(jnp.where(valid, new.x, state.x), jnp.where(valid, new.v, state.v)), info


def _implicit(cloth: Cloth, state: State, dt, integ: ImplicitEuler, prev=None, start=None, tight=False,
              layout: Layout | None = None):
    x0, v0, h = state.x, state.v, dt
    valid = valid_inputs(cloth, dt)
    p = pr.StepProblem.build(cloth, x0, v0, h, prev, layout)
    rtol = integ.resolved_rtol(x0.dtype)
    p_const = jax.tree_util.tree_map(lax.stop_gradient, p)
    if start is not None and p.contact is None:  # contact starts from x^n or its push-out
        start = lax.stop_gradient(start(p_const))
    else:
        start = None
    s = newton(p_const, integ, rtol, start, tight_first=tight)
    end = s.iterate
    w = solution(integ, end.w, p)
    free = p.free > 0
    u = jnp.where(free, p.displacement(w), 0.0)  # pins do not move
    x, v = x0 + u, jnp.where(free, p.velocity(w), 0.0)
    ok = valid & ~s.fail & bounded(cloth, x, v)
    x, v = jnp.where(ok, x, x0), jnp.where(ok, v, v0)
    gnorm = jnp.linalg.norm(end.grad)
    info = StepInfo(newton_iters=s.it, cg_iters=s.cg, grad_norm=jnp.where(jnp.isfinite(gnorm), gnorm, jnp.inf),
                    rel_grad=end.rel, step_size=s.alpha, backtracks=s.bt, residual=s.res,
                    converged=ok & (end.rel <= rtol), stable=ok, valid=valid,
                    cond_bound=pr.condition_bound(p_const, end.terms), trace=s.trace)
    return State(x, v), info


@functools.partial(jax.jit, static_argnames=("integrator",))
def _step(cloth, layout, state, dt, integrator, prev=None, guess=None, history=None):
    """One step on ``cloth`` with its ``layout`` (``_layout.layout_of``); an implicit one
    may start Newton from ``guess`` (end-of-step positions, ``(N, 3)``) or from the
    extrapolation of a :class:`History`."""
    if isinstance(integrator, ExplicitEuler):
        return _explicit(cloth, state, dt, integrator, layout)
    start, tight = None, False
    if guess is not None:
        start = lambda p: (guess - p.x0) - p.prediction  # noqa: E731
    elif history is not None:
        start, tight = history.start, history.jerk
    return _implicit(cloth, state, dt, integrator, prev, start, tight, layout)


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
    out = [particle_array(name, a, cloth) for name, a in (("state.x", state.x), ("state.v", state.v))]
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


def step(cloth: Cloth, state: State, dt, integrator=ImplicitEuler(), guess=None) -> tuple[State, StepInfo]:
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

    Returns:
      ``(new_state, StepInfo)`` in the scene's dtype (the state is cast to it).  Pinned
      particles keep their positions exactly.

    On Linux, call ``jaxsim.retain_host_memory()`` once when stepping large cloths one
    step per call: a float64 128x128 grid's step then stops faulting its 56 MB of scratch
    memory in again at every call (35.1 -> 20.1 ms per step, README "Compilation and memory").
    """
    state = check_inputs(cloth, state, dt, integrator)
    guess = None if guess is None else particle_array("guess", guess, cloth)
    return _step(cloth, layout_of(cloth.springs, cloth.rest), state, jnp.asarray(dt, cloth.dtype), integrator,
                 guess=guess)


@functools.partial(jax.jit, static_argnames=("n_steps", "integrator", "checkpoint"))
def _rollout(cloth, layout, state, dt, n_steps, integrator, checkpoint=False, path=None, resume=None):
    extrapolate = isinstance(integrator, ImplicitEuler) and integrator.extrapolate and not cloth.colliders

    def f(carry, cols):
        s, prev, history = carry  # history: None unless extrapolating
        if cols is None:
            s2, info = _step(cloth, layout, s, dt, integrator, history=history)
        else:  # a collider path: no extrapolation (colliders)
            s2, info = _step(dataclasses.replace(cloth, colliders=cols), layout, s, dt, integrator, prev)
        history = None if history is None else history.advance(s.v, info, integrator.extrapolate)
        return (s2, cols if cols is not None else prev, history), (s2, info)

    if checkpoint:
        f = jax.checkpoint(f, prevent_cse=False)
    prev0 = cloth.colliders if path is not None else None
    history = History.before(cloth, state.x, state.v, dt, integrator.extrapolate, resume, layout) if extrapolate else None
    _, (states, infos) = lax.scan(f, (state, prev0, history), path, length=n_steps)
    return states, infos


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


def check_resume(cloth: Cloth, resume, batch: int | None = None):
    """``(v (min(T, 3), N, 3), converged (), newton_iters ())`` of a previous rollout's
    ``(states, infos)``: the last velocities, all that ``History.before`` reads, so the
    compiled rollout does not depend on the previous one's length.  ``batch``: ``B``, a
    previous ``batch_rollout``'s outputs (every shape with a leading ``(B,)`` axis)."""
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
    return (v[..., -3:, :, :].astype(cloth.dtype), jnp.asarray(infos.converged[..., -1]),
            jnp.asarray(infos.newton_iters[..., -1]))


def rollout(cloth: Cloth, state: State, dt, n_steps: int, integrator=ImplicitEuler(),
            checkpoint: bool = False, colliders=None, resume=None) -> tuple[State, StepInfo]:
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
        chunks start each step exactly as one long rollout would.  Without it the
        velocities before come from the forces at ``state``, which differ from the
        previous rollout's only through damping's frozen directions (and ``"auto"``
        takes the motion as smooth).  No effect where ``rollout`` does not extrapolate
        (explicit Euler, ``extrapolate=0``, colliders).

    Returns:
      ``(states, infos)`` stacked over a leading ``(n_steps,)`` axis (``states.x`` is
      ``(n_steps, N, 3)``; the initial state is not included).
    """
    state = check_inputs(cloth, state, dt, integrator)
    n_steps = check_int("n_steps", n_steps, 1)
    path = check_path(cloth, colliders, n_steps)
    resume = check_resume(cloth, resume)
    layout = layout_of(cloth.springs, cloth.rest)
    return _rollout(cloth, layout, state, jnp.asarray(dt, cloth.dtype), n_steps, integrator,
                    check_bool("checkpoint", checkpoint), path, resume)
