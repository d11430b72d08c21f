"""Integrator settings: small static dataclasses (hashable, part of the jit cache key)."""

from __future__ import annotations

import dataclasses
import functools
import warnings

import numpy as np

from .._validate import check_bool, check_int, check_real
from ._linear import AUTO_DENSE_MAX_PARTICLES, CG, Auto, Cholesky, Jacobi, TwoLevel, check_linear_solver, resolve

__all__ = ["AUTO_DENSE_MAX_PARTICLES", "BDF2", "TRBDF2", "DEFAULT_RTOL", "MAX_SUBSTEP_DEPTH", "ExplicitEuler", "ImplicitEuler"]

#: Default ``ImplicitEuler.rtol`` per dtype: the relative gradient a converged step
#: reaches with margin (measured on the lab cloth, the stiff scenes and the extreme
#: cases of the test suite; see the README's float32 section).
DEFAULT_RTOL = {np.dtype(np.float32): 1e-4, np.dtype(np.float64): 1e-9}

#: The largest ``ImplicitEuler.max_substep_depth``: ``2^10`` substeps per step.
MAX_SUBSTEP_DEPTH = 10


@dataclasses.dataclass(frozen=True)
class ExplicitEuler:
    """Symplectic Euler with ``substeps`` substeps per step: ``v += (g + F/m) dt'``, ``x += v dt'``.

    The lab's reference takes 1000 substeps per 1/60 s frame.
    """

    substeps: int = 1

    def __post_init__(self):
        object.__setattr__(self, "substeps", check_int("substeps", self.substeps, 1))


@dataclasses.dataclass(frozen=True)
class ImplicitEuler:
    """Backward Euler by Newton's method on the incremental potential (17.19).

    Attributes:
      linear_solver: the Newton direction's linear solve: ``cloth.Cholesky()`` (dense,
        the assembled Hessian), ``cloth.CG(preconditioner=cloth.Jacobi() | cloth.TwoLevel(),
        tol=, forcing=, max_iters=)`` (matrix-free PCG), or ``cloth.Auto(cg=CG())`` (default,
        also ``"auto"``): Cholesky up to ``AUTO_DENSE_MAX_PARTICLES`` particles, its CG
        above (``jaxsim.cloth._linear``).
      newton_iters: maximum Newton iterations per step.
      tol: ``None`` (default): Newton stops as soon as the gradient test below holds,
        at the start too (0 iterations for a cloth already at rest).  A number (m/s):
        the lab's step test as well: Newton stops once ``max|dx| / h < tol`` and the
        gradient test holds, or the gradient test holds and an iteration no longer
        halves the relative gradient (its noise floor, where float32 cannot meet the
        step test; ``_implicit.newton.FLOOR_RATIO``).  The step test costs an iteration that
        does not make the step more accurate: on the lab cloth and a 32x32 grid the
        second float32 iteration leaves the error against a float64 reference at its
        float32 level (README, "Residual stop").  Either way Newton also stops when
        the gradient is at rounding level or when a step is at the rounding level of
        the displacement (nothing more can be resolved in the dtype).
      rtol: the gradient test and the meaning of ``StepInfo.converged``:
        ``max_i |grad_i g| <= rtol * max_i scale_i``, with ``scale_i`` the size of the
        terms the gradient sums at particle ``i`` (inertia, gravity, spring and damping
        forces; ``jaxsim.cloth._problem.force_scale``).  ``None``: ``DEFAULT_RTOL`` of
        the scene's dtype.
      line_search: backtracking (Armijo) line search, Algorithm 2 of the lab.
      project_psd: ``"auto"`` (default): Newton uses the exact spring blocks.  When the
        Hessian they make is not positive definite (PCG meets non-positive curvature,
        or Cholesky fails), that iteration's direction is recomputed on the exact
        Hessian with the inertia term doubled (``direction.SHIFT``), and if that is
        still indefinite, with every block projected.  Once the relative gradient is
        below 1e-3 and the exact Hessian was indefinite, Newton takes full steps to the
        exact Hessian's stationary point (PCG through negative curvature), up to six, kept
        if one lowers the relative gradient (else Newton returns to where they began):
        near a buckling cloth's saddle the shifted Hessian
        converges only linearly, the exact one quadratically, and a stationary point of
        (17.19) solves backward Euler's equations (``_implicit.newton.STATIONARY_REL``).  ``True``: always clamp each
        spring block's negative (compression) eigenvalue at 0 (the lab's choice; on stiff, light cloth it turns
        Newton's quadratic convergence into linear).  ``False``: never project.
      max_backtracks: line-search halvings before giving up on a step.
      trace: log every Newton iteration in ``StepInfo.trace`` (a ``NewtonTrace``:
        objective, relative gradient, step, line search, CG iterations and which
        Hessian gave the direction).  Off by default: the log is written inside the
        Newton loop.
      extrapolate: where ``rollout`` starts each step's Newton solve (the lab's start
        ``x^n`` is kept wherever its incremental potential is lower; README, "Extrapolated
        start").  Before a rollout's first step the velocities ``v^{-1}, v^{-2}`` are those of
        the backward-Euler motion that ends at the given state (from its forces:
        ``_implicit.extrapolate.History.before``), or the previous rollout's with ``resume``.
        ``1``: the constant-acceleration extrapolation
        ``x^n + h (2 v^n - v^{n-1})``; on a smoothly
        moving cloth one Newton iteration closer to the solution.  ``2``: the
        constant-jerk extrapolation ``x^n + h (3 v^n - 3 v^{n-1} + v^{n-2})``,
        whose first PCG solve runs to the relative residual ``rtol / rel`` that the
        gradient test needs (at least ``CG.tol``, at most the forcing term's): on a 32x32
        lab-like grid one Newton iteration from it meets float64's gradient test
        (relative gradient 2.6e-10 to 3.2e-10, against 5e-9 to 1.2e-8 from the linear
        one), but on stiff, buckling cloth it costs iterations.  ``"auto"`` (default, also ``True``): ``2`` on a rollout's
        first step and after a step that converged within ``_implicit.extrapolate.SMOOTH_NEWTON``
        iterations, else ``1``.  ``False`` (``0``):
        the lab's start.  Scenes with colliders always start from ``x^n`` (or its push-out
        off a moving collider).  ``step`` takes the same start as ``guess``.
      max_substep_depth: adaptive substeps (``_implicit.substeps``).  A step whose Newton
        solve does not meet the gradient test within ``newton_iters`` (or fails) is
        retried as two half steps, each of which may be halved again, down to
        ``h / 2^max_substep_depth`` (default 4: up to 16 substeps); an attempt at that
        depth is kept if it could be taken, converged or not.  ``StepInfo.substeps``
        counts the substeps a step took, and ``converged`` means every one converged.
        Inside the compiled step (a bounded ``lax.while_loop``); a step that converges
        at once costs what it did without.  In ``rollout`` each step first attempts the
        level the step before left (``StepInfo.memory``: the coarsest it accepted, one
        coarser where that pays; ``_implicit.substeps.remember``); ``step`` attempts the
        whole step first.  ``0``: no substeps (a step that does not converge is returned unconverged).
      solver, preconditioner, cg_tol, cg_forcing, cg_max_iters: the earlier spelling of
        ``linear_solver`` (``solver="dense" | "cg" | "auto"``, ``preconditioner="jacobi" |
        "two_level"``), kept for one release: a ``DeprecationWarning``, then the same
        settings as the ``linear_solver`` they stand for (and equal to them).
    """

    linear_solver: Cholesky | CG | Auto | str = "auto"
    newton_iters: int = 20
    tol: float | None = None
    rtol: float | None = None
    line_search: bool = True
    project_psd: bool | str = "auto"
    max_backtracks: int = 30
    trace: bool = False
    extrapolate: bool | int | str = "auto"
    max_substep_depth: int = 4
    solver: str | None = dataclasses.field(default=None, repr=False)
    preconditioner: str | None = dataclasses.field(default=None, repr=False)
    cg_tol: float | None = dataclasses.field(default=None, repr=False)
    cg_forcing: float | None = dataclasses.field(default=None, repr=False)
    cg_max_iters: int | None = dataclasses.field(default=None, repr=False)

    def __post_init__(self):
        set_ = functools.partial(object.__setattr__, self)
        set_("linear_solver", _from_old_keywords(self))
        for name in _OLD:
            set_(name, None)
        set_("newton_iters", check_int("newton_iters", self.newton_iters, 1))
        set_("max_backtracks", check_int("max_backtracks", self.max_backtracks, 0))
        set_("max_substep_depth", check_int("max_substep_depth", self.max_substep_depth, 0))
        if self.max_substep_depth > MAX_SUBSTEP_DEPTH:
            raise ValueError(f"max_substep_depth must be <= {MAX_SUBSTEP_DEPTH} (2^depth substeps), "
                             f"got {self.max_substep_depth}")
        if self.tol is not None:
            set_("tol", check_real("tol", self.tol, minimum=0.0))
        if self.rtol is not None:
            set_("rtol", check_real("rtol", self.rtol, minimum=0.0))
        set_("line_search", check_bool("line_search", self.line_search))
        set_("trace", check_bool("trace", self.trace))
        e = self.extrapolate
        if isinstance(e, (bool, np.bool_)):
            set_("extrapolate", "auto" if e else 0)
        elif isinstance(e, (int, np.integer)) and e in (0, 1, 2):
            set_("extrapolate", int(e))
        elif not (isinstance(e, str) and e == "auto"):
            raise ValueError(f"extrapolate must be 'auto', True, False, 0, 1 or 2, got {e!r}")
        if self.project_psd != "auto":
            set_("project_psd", check_bool("project_psd (True, False or 'auto')", self.project_psd))

    def resolved_rtol(self, dtype) -> float:
        """``rtol``, or the dtype's default (``DEFAULT_RTOL``)."""
        return DEFAULT_RTOL[np.dtype(dtype)] if self.rtol is None else self.rtol

    def linear(self, n_particles: int) -> Cholesky | CG:
        """The linear solver for a cloth of ``n_particles`` (an ``Auto`` resolved)."""
        return resolve(self.linear_solver, n_particles)


@dataclasses.dataclass(frozen=True)
class BDF2(ImplicitEuler):
    """The two-step backward differentiation formula, by the same Newton solve.

    ``x^{n+1} - a x^n + b x^{n-1} = beta h v^{n+1}`` and the same for the velocities
    with the forces, with variable-step coefficients from the ratio to the step before
    (``_implicit.bdf2``): second order in ``h`` where backward Euler is first, so much
    less numerical damping.  Each step is backward Euler's problem from a shifted state
    over ``beta h``, so every ``ImplicitEuler`` option (the linear solve, the Newton
    settings, the extrapolated start, adaptive substeps, the implicit derivative) means
    the same here.  A rollout's first step, and a substep more than
    ``_implicit.bdf2.MAX_RATIO`` times longer than the one before, is a backward-Euler
    step; ``step(..., previous=)`` gives it the state one step before, and
    ``rollout(resume=)`` the previous rollout's last step.  With colliders the contact
    terms are those of the step from ``x^n`` (the shifted state may lie inside one), and
    Newton starts there.
    """


@dataclasses.dataclass(frozen=True)
class TRBDF2(ImplicitEuler):
    """TR-BDF2 (Bank et al. 1985; Hosea & Shampine 1996): per step, the trapezoidal rule
    over ``(2 - sqrt 2) h`` and BDF2 over the rest (``_implicit.trbdf2``).

    Second order and L-stable like BDF2, with about a fifth of its local error, for two
    Newton solves a step.  Each stage is backward Euler's problem from a shifted state,
    so every ``ImplicitEuler`` option means the same here, per stage; adaptive substeps
    halve a stage that does not converge.  The trapezoidal stage starts from the
    acceleration the step before solved for (before a rollout's first step: the forces
    at the state; with colliders or wind, whose forces a state does not give, the first
    step's first stage is backward Euler).  ``extrapolate`` (nonzero) starts each stage's
    Newton solve at the positions whose velocity is ``v + h a`` (where the incremental
    potential is lower there), with a first PCG solve aimed at the gradient test (``2``:
    always; ``"auto"``: after a stage that converged within two iterations).
    ``StepInfo.substeps`` counts both stages' (2 for a step whose stages were not halved),
    and the other diagnostics sum or take the worse of the two.
    """


_OLD = ("solver", "preconditioner", "cg_tol", "cg_forcing", "cg_max_iters")
_OLD_SOLVERS = ("dense", "cg", "auto")
_OLD_PRECONDITIONERS = {"jacobi": Jacobi(), "two_level": TwoLevel()}


def _from_old_keywords(s: ImplicitEuler):
    """``linear_solver``, built from the deprecated keywords where any is given."""
    given = [n for n in _OLD if getattr(s, n) is not None]
    if not given:
        return check_linear_solver(s.linear_solver)
    if check_linear_solver(s.linear_solver) != Auto():
        raise ValueError(f"give linear_solver= or the old keywords {given}, not both")
    warnings.warn(f"ImplicitEuler({', '.join(given)}=...) is deprecated: use linear_solver=cloth.Cholesky() or "
                  f"cloth.CG(preconditioner=cloth.Jacobi() | cloth.TwoLevel(), tol=, forcing=, max_iters=)",
                  DeprecationWarning, stacklevel=4)
    solver = "auto" if s.solver is None else s.solver
    if not isinstance(solver, str) or solver not in _OLD_SOLVERS:
        raise ValueError(f"solver must be one of {_OLD_SOLVERS}, got {s.solver!r}")
    pre = "jacobi" if s.preconditioner is None else s.preconditioner
    if not isinstance(pre, str) or pre not in _OLD_PRECONDITIONERS:
        raise ValueError(f"preconditioner must be one of {tuple(_OLD_PRECONDITIONERS)}, got {s.preconditioner!r}")
    if solver == "dense":
        return Cholesky()
    cg = CG(preconditioner=_OLD_PRECONDITIONERS[pre], tol=1e-6 if s.cg_tol is None else s.cg_tol,
            forcing=1e-2 if s.cg_forcing is None else s.cg_forcing,
            max_iters=500 if s.cg_max_iters is None else s.cg_max_iters)
    return cg if solver == "cg" else Auto(cg)
