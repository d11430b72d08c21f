"""Integrator settings: small static dataclasses (hashable, part of the jit cache key)."""

from __future__ import annotations

import dataclasses

SOLVERS = ("dense", "cg", "auto")

#: ``solver="auto"`` uses dense Cholesky up to this many particles, CG above.  Measured
#: on lab-like grids (converged step, float64, 2-core CPU): dense and CG take the same
#: time up to 4x4 = 16 particles (0.13 ms), CG is faster from 5x5 = 25 (0.28 against
#: 0.31 ms), 2.1x faster at 36 and 3.2x at 64.
AUTO_DENSE_MAX_PARTICLES = 16


@dataclasses.dataclass(frozen=True)
class ExplicitEuler:
    """Symplectic Euler with ``substeps`` substeps per step: ``v += (g + F/m) dt'``, ``x += v dt'``.

    The lab's reference takes 1000 substeps per 1/60 s frame.
    """

    substeps: int = 1

    def __post_init__(self):
        if not (isinstance(self.substeps, int) and self.substeps >= 1):
            raise ValueError(f"substeps must be an int >= 1, got {self.substeps!r}")


@dataclasses.dataclass(frozen=True)
class ImplicitEuler:
    """Backward Euler by Newton's method on the incremental potential (17.19).

    Attributes:
      solver: ``"dense"`` (Cholesky on the assembled Hessian), ``"cg"`` (matrix-free
        block-Jacobi PCG) or ``"auto"`` (dense up to ``AUTO_DENSE_MAX_PARTICLES``).
      newton_iters: maximum Newton iterations per step.
      tol: stop when ``max|dx| / h < tol`` (m/s), or when ``max|dx|`` is at the rounding
        level of the positions (``4 eps max|x|``), which is what float32 can resolve.
      line_search: backtracking (Armijo) line search, Algorithm 2 of the lab.
      project_psd: clamp each spring block's negative (compression) eigenvalue at 0.
      cg_tol: relative residual at which PCG stops.
      cg_max_iters: PCG iteration cap per Newton iteration.
      max_backtracks: line-search halvings before giving up on a step.
    """

    solver: str = "auto"
    newton_iters: int = 20
    tol: float = 1e-6
    line_search: bool = True
    project_psd: bool = True
    cg_tol: float = 1e-6
    cg_max_iters: int = 500
    max_backtracks: int = 30

    def __post_init__(self):
        if self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {self.solver!r}")
        if not (isinstance(self.newton_iters, int) and self.newton_iters >= 1):
            raise ValueError(f"newton_iters must be an int >= 1, got {self.newton_iters!r}")
        if not (isinstance(self.cg_max_iters, int) and self.cg_max_iters >= 1):
            raise ValueError(f"cg_max_iters must be an int >= 1, got {self.cg_max_iters!r}")
        if not self.tol >= 0 or not self.cg_tol >= 0:
            raise ValueError("tol and cg_tol must be >= 0")

    def resolved_solver(self, n_particles: int) -> str:
        if self.solver != "auto":
            return self.solver
        return "dense" if n_particles <= AUTO_DENSE_MAX_PARTICLES else "cg"
