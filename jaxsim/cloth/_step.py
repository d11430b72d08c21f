"""Time stepping: explicit (symplectic) Euler substeps and implicit Euler by Newton."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._dataclass import is_concrete, pytree_dataclass
from .._validate import check_finite, check_shape
from . import _energy as en
from ._integrators import ExplicitEuler, ImplicitEuler
from ._linsolve import block_inverse, dense_solve, pcg
from ._scene import Cloth, State, spring_sum

#: Armijo constants of the backtracking line search (lab Algorithm 2).
BETA, GAMMA = 0.5, 1e-4


@pytree_dataclass
class StepInfo:
    """Diagnostics of one step (a leading ``T`` axis after ``rollout``).

    Attributes:
      newton_iters: Newton iterations taken (0 for explicit Euler).
      cg_iters: PCG iterations summed over the Newton iterations (0 unless CG).
      grad_norm: ``|grad g|`` over free particles at the returned positions (N).
      step_size: line-search step ``alpha`` of the last Newton iteration.
      backtracks: line-search halvings summed over the Newton iterations.
      residual: relative linear-solve residual of the last Newton iteration.
      converged: Newton met ``max|dx|/h < tol`` (explicit: same as ``stable``).
      stable: the state is finite and bounded; when False the step was rejected and the
        returned state is the last good one (never NaN).
    """

    newton_iters: jax.Array
    cg_iters: jax.Array
    grad_norm: jax.Array
    step_size: jax.Array
    backtracks: jax.Array
    residual: jax.Array
    converged: jax.Array
    stable: jax.Array


def _bounded(cloth, x, v):
    """Finite, and not flown off to a distance no simulation of this scene reaches."""
    extent = jnp.max(jnp.abs(cloth.rest)) + 1.0
    return jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(v)) & (jnp.max(jnp.abs(x)) < 1e6 * extent)


def _damping_forces(cloth, x, v):
    e, _ = en.spring_directions(cloth, x)
    i, j = cloth.springs[:, 0], cloth.springs[:, 1]
    f = cloth.damping * jnp.sum((v[j] - v[i]) * e, axis=-1)[:, None] * e
    return jnp.zeros_like(x).at[i].add(f).at[j].add(-f)


def _explicit(cloth: Cloth, state: State, dt, integ: ExplicitEuler):
    h = dt / integ.substeps
    free = (~cloth.pinned)[:, None]

    def sub(c, _):
        x, v, ok = c
        F = en.forces(cloth, x)  # springs + gravity, from jax.grad(energy)
        if cloth.damped:
            F = F + _damping_forces(cloth, x, v)
        v_new = jnp.where(free, v + h * F / cloth.mass[:, None], 0.0)
        x_new = x + h * v_new
        good = ok & _bounded(cloth, x_new, v_new)
        return (jnp.where(good, x_new, x), jnp.where(good, v_new, v), good), None

    (x, v, ok), _ = lax.scan(sub, (state.x, state.v, jnp.array(True)), None, length=integ.substeps)
    z = jnp.zeros((), x.dtype)
    info = StepInfo(newton_iters=jnp.int32(0), cg_iters=jnp.int32(0), grad_norm=z, step_size=z,
                    backtracks=jnp.int32(0), residual=z, converged=ok, stable=ok)
    return State(x, v), info


def incremental_potential(x, theta):
    """The lab's incremental potential (17.19) plus the dissipation potential.

    ``g(x) = 1/(2h^2) |x - y|_M^2 + E(x) + D(x)`` with ``y = x^n + h v^n`` (gravity is
    part of ``E``) and ``D`` the frozen-direction damping potential (``_energy`` module
    doc; absent when ``cloth.damped`` is False).

    Args:
      x: ``(N, 3)`` candidate end-of-step positions.
      theta: ``(cloth, x^n (N,3), v^n (N,3), h)``, everything the step depends on.
    """
    cloth, x0, v0, h = theta
    y = x0 + h * v0
    g = 0.5 / h**2 * jnp.sum(cloth.mass[:, None] * (x - y) ** 2) + en.energy(cloth, x)
    damp = _damping_terms(theta)
    if damp is not None:
        i, j = cloth.springs[:, 0], cloth.springs[:, 1]
        g = g + jnp.sum(en.damping_element(x[i], x[j], *damp))
    return g


def _damping_terms(theta):
    cloth, x0, _, h = theta
    if not cloth.damped:
        return None
    e0, d0 = en.spring_directions(cloth, x0)
    return e0, d0, cloth.damping / h


def _block_jacobi(cloth, A, h, free):
    """``r -> D^{-1} r`` with ``D`` the 3x3 diagonal blocks of ``M/h^2 + sum_s A_s`` (identity on pins)."""
    D = spring_sum(cloth, A, signed=False)
    D = D + (cloth.mass / h**2)[:, None, None] * jnp.eye(3, dtype=A.dtype)
    D = jnp.where(free[:, :, None] > 0, D, jnp.broadcast_to(jnp.eye(3, dtype=A.dtype), D.shape))
    Dinv = block_inverse(D)
    return lambda r: jnp.einsum("nab,nb->na", Dinv, r)


def _newton(theta, integ: ImplicitEuler):
    """Newton's method with backtracking line search (lab Algorithm 2) on ``g(., theta)``.

    Returns the end-of-step positions (pins at ``x^n``) and the loop's statistics.
    Runs on ``stop_gradient`` inputs: derivatives come from ``_solution`` instead.
    """
    cloth, x0, v0, h = theta
    N = cloth.num_particles
    free = (~cloth.pinned)[:, None].astype(x0.dtype)
    m = cloth.mass[:, None]
    solver = integ.resolved_solver(N)
    damp = _damping_terms(theta)
    objective = functools.partial(incremental_potential, theta=theta)
    grad = jax.grad(objective)
    spr_i, spr_j = cloth.springs[:, 0], cloth.springs[:, 1]

    def newton_direction(x, gvec, guess):
        b = -gvec * free
        if solver == "dense":
            if integ.project_psd:
                A = en.element_blocks(cloth, x, damp, project_psd=True)
                H = en.assemble(cloth, A)
                H = H + jnp.diag(jnp.repeat(cloth.mass, 3) / h**2)
            else:
                H = jax.hessian(objective)(x).reshape(3 * N, 3 * N)
            f = free.repeat(3, axis=1).reshape(-1)
            H = H * f[:, None] * f[None, :] + jnp.diag(1.0 - f)
            dx = dense_solve(H, b.reshape(-1)).reshape(N, 3)
            return dx, jnp.int32(0), jnp.linalg.norm(H @ dx.reshape(-1) - b.reshape(-1)) / jnp.maximum(jnp.linalg.norm(b), 1e-30)
        # matrix-free PCG
        A = en.element_blocks(cloth, x, damp, project_psd=True) if integ.project_psd else None
        if A is not None:
            def apply_H(p):
                p = p * free
                f = jnp.einsum("sab,sb->sa", A, p[spr_j] - p[spr_i])
                Hp = spring_sum(cloth, f)
                return (Hp + m / h**2 * p) * free + (1.0 - free) * p
            diag_src = A
        else:
            def apply_H(p):
                p = p * free
                Hp = jax.jvp(grad, (x,), (p,))[1]
                return Hp * free + (1.0 - free) * p
            diag_src = en.element_blocks(cloth, x, damp, project_psd=False)
        apply_Minv = _block_jacobi(cloth, diag_src, h, free)
        dx, k, rel = pcg(apply_H, b, guess * free, apply_Minv, tol=integ.cg_tol, max_iters=integ.cg_max_iters)
        return dx, k, rel

    def line_search(x, gx, gvec, dx):
        slope = jnp.sum(gvec * dx)
        if not integ.line_search:
            return dx, jnp.ones((), x.dtype), jnp.int32(0), objective(x + dx)
        # keep every step a descent step
        descent = slope < 0
        dx = jnp.where(descent, dx, -gvec * free * h**2 / m)
        slope = jnp.where(descent, slope, jnp.sum(gvec * dx))

        # rounding allowance: at convergence g changes by less than its last bits
        slack = 8 * jnp.finfo(x.dtype).eps * jnp.abs(gx)

        def cond(c):
            a, k, gnew = c
            armijo = gnew <= gx + GAMMA * a * slope + slack
            return (k < integ.max_backtracks) & ~(armijo & jnp.isfinite(gnew))

        def body(c):
            a, k, _ = c
            a = BETA * a
            return a, k + 1, objective(x + a * dx)

        a, k, gnew = lax.while_loop(cond, body, (jnp.ones((), x.dtype), jnp.int32(0), objective(x + dx)))
        return dx, a, k, gnew

    def cond(c):
        return (c["it"] < integ.newton_iters) & ~c["done"]

    def body(c):
        x = c["x"]
        gvec = grad(x) * free
        dx, k_cg, rel = newton_direction(x, gvec, c["guess"])
        dx, a, k_ls, g_new = line_search(x, c["g"], gvec, dx)  # g(x) carried from the last iteration
        step = a * dx
        x_new = x + step
        ok = jnp.all(jnp.isfinite(x_new))
        x_new = jnp.where(ok, x_new, x)
        # converged: the lab's test, or a step at the rounding level of the positions
        # (float32 cannot resolve max|dx|/h below ~eps*|x|/h, e.g. 1e-5 m/s at h=1/60)
        dmax = jnp.max(jnp.abs(step))
        small = (dmax / h < integ.tol) | (dmax <= 4 * jnp.finfo(x.dtype).eps * jnp.max(jnp.abs(x)))
        return dict(x=x_new, g=jnp.where(ok, g_new, c["g"]), guess=jnp.where(ok, step, jnp.zeros_like(step)),
                    it=c["it"] + 1, done=small | ~ok,
                    fail=c["fail"] | ~ok, cg=c["cg"] + k_cg, bt=c["bt"] + k_ls, alpha=a, res=rel, conv=small & ok)

    z = jnp.zeros((), x0.dtype)
    c0 = dict(x=x0, g=objective(x0), guess=h * v0, it=jnp.int32(0), done=jnp.array(False), fail=jnp.array(False),
              cg=jnp.int32(0), bt=jnp.int32(0), alpha=z, res=z, conv=jnp.array(False))
    c = lax.while_loop(cond, body, c0)
    x = jnp.where(free > 0, c["x"], x0)
    return x, c, jnp.linalg.norm(grad(x) * free)


def _stationarity(u, theta):
    """Root function of the step in the free unknowns ``u (N,3)`` (pinned entries 0).

    ``F(u) = P grad g(P u + (1-P) x^n) + (1-P) u``: its Jacobian ``P H P + (1-P)`` is
    symmetric, and its dependence on the pinned positions ``x^n`` is explicit.
    """
    cloth, x0 = theta[0], theta[1]
    free = (~cloth.pinned)[:, None]
    x = jnp.where(free, u, x0)
    return jnp.where(free, jax.grad(incremental_potential)(x, theta), u)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _solution(integ, u_star, theta):
    """Identity on the converged ``u_star``; its derivative is the implicit-function one.

    ``du*/dtheta = -J^{-1} dF/dtheta`` with ``J = dF/du`` at the solution (one linear
    solve with the exact Hessian, through ``lax.custom_linear_solve`` so reverse mode
    transposes it as the same symmetric solve).  Nothing is differentiated through the
    Newton or CG iterations.
    """
    return u_star


@_solution.defjvp
def _solution_jvp(integ, primals, tangents):
    u_star, theta = primals
    _, theta_dot = tangents
    cloth, _, _, h = theta
    rhs = jax.jvp(lambda th: _stationarity(u_star, th), (theta,), (theta_dot,))[1]

    def matvec(w):
        return jax.jvp(lambda u: _stationarity(u, theta), (u_star,), (w,))[1]

    N = cloth.num_particles
    if integ.resolved_solver(N) == "dense":
        def solve(mv, b):
            eye = jnp.eye(3 * N, dtype=b.dtype).reshape(3 * N, N, 3)
            A = jax.vmap(mv)(eye).reshape(3 * N, 3 * N)
            return jnp.linalg.solve(A, b.reshape(-1)).reshape(N, 3)
    else:
        free = (~cloth.pinned)[:, None].astype(u_star.dtype)
        x = jnp.where(free > 0, u_star, theta[1])
        Minv = _block_jacobi(cloth, en.element_blocks(cloth, x, _damping_terms(theta), project_psd=True), h, free)

        def solve(mv, b):
            return pcg(mv, b, jnp.zeros_like(b), Minv, tol=integ.cg_tol, max_iters=integ.cg_max_iters)[0]

    du = lax.custom_linear_solve(matvec, rhs, solve, symmetric=True)
    return u_star, -du


def _implicit(cloth: Cloth, state: State, dt, integ: ImplicitEuler):
    x0, v0 = state.x, state.v
    h = dt
    if not cloth.damped:  # the step must not read the damping leaf of an undamped scene
        cloth = dataclasses.replace(cloth, damping=jnp.zeros((), x0.dtype))
    theta = (cloth, x0, v0, h)
    x_sol, c, gnorm = _newton(jax.tree_util.tree_map(lax.stop_gradient, theta), integ)
    free = (~cloth.pinned)[:, None]
    u = _solution(integ, jnp.where(free, x_sol, 0.0), theta)
    x = jnp.where(free, u, x0)
    v = (x - x0) / h
    ok = ~c["fail"] & _bounded(cloth, x, v)
    x, v = jnp.where(ok, x, x0), jnp.where(ok, v, v0)
    info = StepInfo(newton_iters=c["it"], cg_iters=c["cg"], grad_norm=gnorm, step_size=c["alpha"],
                    backtracks=c["bt"], residual=c["res"], converged=c["conv"], stable=ok)
    return State(x, v), info


@functools.partial(jax.jit, static_argnames=("integrator",))
def _step(cloth, state, dt, integrator):
    if isinstance(integrator, ExplicitEuler):
        return _explicit(cloth, state, dt, integrator)
    return _implicit(cloth, state, dt, integrator)


def check_inputs(cloth: Cloth, state: State, dt, integrator) -> None:
    """Boundary validation (raises ``ValueError``/``TypeError`` before any tracing)."""
    if not isinstance(cloth, Cloth):
        raise TypeError(f"cloth must be a jaxsim.cloth.Cloth, got {type(cloth).__name__}")
    if not isinstance(state, State):
        raise TypeError(f"state must be a jaxsim.cloth.State, got {type(state).__name__}")
    if not isinstance(integrator, (ExplicitEuler, ImplicitEuler)):
        raise TypeError(f"integrator must be ExplicitEuler or ImplicitEuler, got {type(integrator).__name__}")
    N = cloth.num_particles
    for name, a in (("state.x", state.x), ("state.v", state.v)):
        if is_concrete(a):
            check_finite(name, check_shape(name, a, (N, 3)))
        elif tuple(a.shape) != (N, 3):
            raise ValueError(f"{name} must have shape ({N}, 3), got {tuple(a.shape)}")
    if is_concrete(dt):
        if np.ndim(dt) != 0 or not np.isfinite(dt) or not float(dt) > 0:
            raise ValueError(f"dt must be a finite scalar > 0, got {dt!r}")


def step(cloth: Cloth, state: State, dt, integrator=ImplicitEuler()) -> tuple[State, StepInfo]:
    """Advance ``state`` by ``dt`` seconds.

    Args:
      cloth: the scene.
      state: ``State(x (N,3), v (N,3))``.
      dt: time step (s), > 0.
      integrator: ``ExplicitEuler(substeps)`` or ``ImplicitEuler(...)``.

    Returns:
      ``(new_state, StepInfo)``.  Pinned particles keep their positions exactly.
    """
    check_inputs(cloth, state, dt, integrator)
    return _step(cloth, state, jnp.asarray(dt, cloth.dtype), integrator)


@functools.partial(jax.jit, static_argnames=("n_steps", "integrator", "checkpoint"))
def _rollout(cloth, state, dt, n_steps, integrator, checkpoint=False):
    def f(s, _):
        s2, info = _step(cloth, s, dt, integrator)
        return s2, (s2, info)

    if checkpoint:
        f = jax.checkpoint(f, prevent_cse=False)
    _, (states, infos) = lax.scan(f, state, None, length=n_steps)
    return states, infos


def rollout(cloth: Cloth, state: State, dt, n_steps: int, integrator=ImplicitEuler(),
            checkpoint: bool = False) -> tuple[State, StepInfo]:
    """``n_steps`` steps in one ``lax.scan``.

    Differentiable end to end: implicit steps carry implicit-function derivatives (one
    extra linear solve per step in reverse mode), explicit substeps are differentiated
    through the scan.

    Args:
      checkpoint: rematerialise each step in reverse mode (``jax.checkpoint``), so the
        backward pass keeps only the per-step states, ``O(T)`` of them, instead of every
        step's linearisation.  No effect on values or on forward evaluation.

    Returns:
      ``(states, infos)`` stacked over a leading ``(n_steps,)`` axis (``states.x`` is
      ``(n_steps, N, 3)``; the initial state is not included).
    """
    check_inputs(cloth, state, dt, integrator)
    if not (isinstance(n_steps, (int, np.integer)) and n_steps >= 1):
        raise ValueError(f"n_steps must be an int >= 1, got {n_steps!r}")
    return _rollout(cloth, state, jnp.asarray(dt, cloth.dtype), int(n_steps), integrator, bool(checkpoint))
