"""Integrator settings: small static dataclasses (hashable, part of the jit cache key)."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from .._validate import check_bool, check_int, check_real

SOLVERS = ("dense", "cg", "auto")
PRECONDITIONERS = ("jacobi", "two_level")

#: ``solver="auto"`` uses dense Cholesky up to this many particles, CG above.  Measured
#: on lab-like grids (converged step, float64, 2-core CPU): dense and CG take the same
#: time up to 4x4 = 16 particles (0.13 ms), CG is faster from 5x5 = 25 (0.28 against
#: 0.31 ms), 2.1x faster at 36 and 3.2x at 64.
AUTO_DENSE_MAX_PARTICLES = 16

#: Default ``ImplicitEuler.rtol`` per dtype: the relative gradient a converged step
#: reaches with margin (measured on the lab cloth, the stiff scenes and the extreme
#: cases of the test suite; see the README's float32 section).
DEFAULT_RTOL = {np.dtype(np.float32): 1e-4, np.dtype(np.float64): 1e-9}


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
      solver: ``"dense"`` (Cholesky on the assembled Hessian), ``"cg"`` (matrix-free
        block-Jacobi PCG) or ``"auto"`` (dense up to ``AUTO_DENSE_MAX_PARTICLES``).
      newton_iters: maximum Newton iterations per step.
      tol: ``None`` (default): Newton stops as soon as the gradient test below holds,
        at the start too (0 iterations for a cloth already at rest).  A number (m/s):
        the lab's step test as well: Newton stops once ``max|dx| / h < tol`` and the
        gradient test holds, or the gradient test holds and an iteration no longer
        halves the relative gradient (its noise floor, where float32 cannot meet the
        step test; ``_newton.FLOOR_RATIO``).  The step test costs an iteration that
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
        Hessian with the inertia term doubled (``_newton.SHIFT``), and if that is
        still indefinite, with every block projected.  Once the relative gradient is
        below 1e-3 and the exact Hessian was indefinite, Newton takes full steps to the
        exact Hessian's stationary point (PCG through negative curvature), up to six, kept
        if one lowers the relative gradient (else Newton returns to where they began):
        near a buckling cloth's saddle the shifted Hessian
        converges only linearly, the exact one quadratically, and a stationary point of
        (17.19) solves backward Euler's equations (``_newton.STATIONARY_REL``).  ``True``: always clamp each
        spring block's negative (compression) eigenvalue at 0 (the lab's choice; on stiff, light cloth it turns
        Newton's quadratic convergence into linear).  ``False``: never project.
      preconditioner: PCG's preconditioner.  ``"jacobi"`` (default): the 3x3 diagonal
        blocks.  ``"two_level"``: block Jacobi around a coarse Galerkin solve on at most
        64 aggregates of particles (``jaxsim.cloth._coarse``); two extra operator
        products per CG iteration, for 8-14x fewer CG iterations on stiff, light cloth
        (``k h^2 / m`` in the hundreds; scene C in the README runs 1.4-2.4x faster), slower
        on soft cloth.
      cg_tol: relative residual at which PCG stops (the floor of the forcing term below).
      cg_forcing: inexact Newton's forcing term (Eisenstat & Walker 1996): each
        iteration's PCG stops at the relative residual ``max(cg_tol, min(cg_forcing,
        rel))``, with ``rel`` the current relative gradient, so early iterations solve
        loosely and the last ones to ``cg_tol`` (the local convergence stays
        superlinear).  ``0`` always solves to ``cg_tol``, and so does a single Newton
        iteration (``newton_iters=1``, the lab's linearised step).
      cg_max_iters: PCG iteration cap per Newton iteration.
      max_backtracks: line-search halvings before giving up on a step.
      trace: log every Newton iteration in ``StepInfo.trace`` (a ``NewtonTrace``:
        objective, relative gradient, step, line search, CG iterations and which
        Hessian gave the direction).  Off by default: the log is written inside the
        Newton loop.
      extrapolate: where ``rollout`` starts each step's Newton solve (the lab's start
        ``x^n`` is kept wherever its incremental potential is lower; README, "Extrapolated
        start").  Before a rollout's first step the velocities ``v^{-1}, v^{-2}`` are those of
        the backward-Euler motion that ends at the given state (from its forces:
        ``_extrapolate.History.before``), or the previous rollout's with ``resume``.
        ``1``: the constant-acceleration extrapolation
        ``x^n + h (2 v^n - v^{n-1})``; on a smoothly
        moving cloth one Newton iteration closer to the solution.  ``2``: the
        constant-jerk extrapolation ``x^n + h (3 v^n - 3 v^{n-1} + v^{n-2})``,
        whose first PCG solve runs to the relative residual ``rtol / rel`` that the
        gradient test needs (at least ``cg_tol``, at most the forcing term's): on a 32x32
        lab-like grid one Newton iteration from it meets float64's gradient test
        (relative gradient 2.6e-10 to 3.2e-10, against 5e-9 to 1.2e-8 from the linear
        one), but on stiff, buckling cloth it costs iterations.  ``"auto"`` (default, also ``True``): ``2`` on a rollout's
        first step and after a step that converged within ``_extrapolate.SMOOTH_NEWTON``
        iterations, else ``1``.  ``False`` (``0``):
        the lab's start.  Scenes with colliders always start from ``x^n`` (or its push-out
        off a moving collider).  ``step`` takes the same start as ``guess``.
    """

    solver: str = "auto"
    newton_iters: int = 20
    tol: float | None = None
    rtol: float | None = None
    line_search: bool = True
    project_psd: bool | str = "auto"
    preconditioner: str = "jacobi"
    cg_tol: float = 1e-6
    cg_forcing: float = 1e-2
    cg_max_iters: int = 500
    max_backtracks: int = 30
    trace: bool = False
    extrapolate: bool | int | str = "auto"

    def __post_init__(self):
        if not isinstance(self.solver, str) or self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {self.solver!r}")
        if not isinstance(self.preconditioner, str) or self.preconditioner not in PRECONDITIONERS:
            raise ValueError(f"preconditioner must be one of {PRECONDITIONERS}, got {self.preconditioner!r}")
        set_ = functools.partial(object.__setattr__, self)
        set_("newton_iters", check_int("newton_iters", self.newton_iters, 1))
        set_("cg_max_iters", check_int("cg_max_iters", self.cg_max_iters, 1))
        set_("max_backtracks", check_int("max_backtracks", self.max_backtracks, 0))
        if self.tol is not None:
            set_("tol", check_real("tol", self.tol, minimum=0.0))
        set_("cg_tol", check_real("cg_tol", self.cg_tol, minimum=0.0))
        set_("cg_forcing", check_real("cg_forcing", self.cg_forcing, minimum=0.0))
        if self.cg_forcing >= 1:
            raise ValueError(f"cg_forcing must be < 1, got {self.cg_forcing!r}")
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

    def resolved_solver(self, n_particles: int) -> str:
        if self.solver != "auto":
            return self.solver
        return "dense" if n_particles <= AUTO_DENSE_MAX_PARTICLES else "cg"
