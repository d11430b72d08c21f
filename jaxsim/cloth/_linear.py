"""The Newton direction's linear solve, chosen by a settings object (frozen and hashable).

``ImplicitEuler(linear_solver=...)`` takes :class:`Cholesky` (dense, the assembled
``(3N, 3N)`` Hessian), :class:`CG` (matrix-free preconditioned conjugate gradients, with a
:class:`Jacobi` or :class:`TwoLevel` preconditioner), or :class:`Auto` (the default, also
spelled ``"auto"``): Cholesky up to ``AUTO_DENSE_MAX_PARTICLES`` particles, its ``CG``
above.
"""

from __future__ import annotations

import dataclasses

from .._validate import check_int, check_real

#: ``linear_solver="auto"`` uses dense Cholesky up to this many particles, CG above.
#: Measured on lab-like grids (converged step, float64, 2-core CPU): dense and CG take the
#: same time up to 4x4 = 16 particles (0.13 ms), CG is faster from 5x5 = 25 (0.28 against
#: 0.31 ms), 2.1x faster at 36 and 3.2x at 64.
AUTO_DENSE_MAX_PARTICLES = 16


def _by_name(self) -> int:
    """A field-less setting's hash: its class's (distinct kinds, distinct jit cache keys)."""
    return hash(type(self).__qualname__)


@dataclasses.dataclass(frozen=True)
class Cholesky:
    """Cholesky on the assembled ``(3N, 3N)`` Hessian (LU where it is indefinite); ``O(N^3)``."""

    __hash__ = _by_name


@dataclasses.dataclass(frozen=True)
class Jacobi:
    """PCG's block-Jacobi preconditioner: the inverted ``3x3`` diagonal blocks (the default)."""

    __hash__ = _by_name


@dataclasses.dataclass(frozen=True)
class TwoLevel:
    """Block Jacobi around a coarse Galerkin solve on at most 64 aggregates of particles
    (``jaxsim.cloth._coarse``): two extra operator products per CG iteration, for 8-14x
    fewer CG iterations on stiff, light cloth (``k h^2 / m`` in the hundreds; see
    docs/cloth.md), slower on soft cloth."""

    __hash__ = _by_name


@dataclasses.dataclass(frozen=True)
class CG:
    """Matrix-free preconditioned conjugate gradients on the Hessian-vector product.

    Attributes:
      preconditioner: :class:`Jacobi` (default) or :class:`TwoLevel`.
      tol: relative residual at which PCG stops (the floor of the forcing term below).
      forcing: inexact Newton's forcing term (Eisenstat & Walker 1996): each
        iteration's PCG stops at the relative residual ``max(tol, min(forcing, rel))``,
        with ``rel`` the current relative gradient, so early iterations solve loosely and
        the last ones to ``tol`` (the local convergence stays superlinear).  ``0`` always
        solves to ``tol``, and so does a single Newton iteration (``newton_iters=1``).
      max_iters: PCG iteration cap per Newton iteration.

    Raises:
      ValueError: a preconditioner that is not ``Jacobi()`` or ``TwoLevel()``, a negative
        ``tol``, ``forcing`` outside ``[0, 1)``, or ``max_iters < 1``.
    """

    preconditioner: Jacobi | TwoLevel = Jacobi()
    tol: float = 1e-6
    forcing: float = 1e-2
    max_iters: int = 500

    def __post_init__(self):
        if not isinstance(self.preconditioner, (Jacobi, TwoLevel)):
            raise ValueError(f"CG preconditioner must be cloth.Jacobi() or cloth.TwoLevel(), got "
                             f"{self.preconditioner!r}")
        object.__setattr__(self, "tol", check_real("CG tol", self.tol, minimum=0.0))
        object.__setattr__(self, "forcing", check_real("CG forcing", self.forcing, minimum=0.0))
        if self.forcing >= 1:
            raise ValueError(f"CG forcing must be < 1, got {self.forcing!r}")
        object.__setattr__(self, "max_iters", check_int("CG max_iters", self.max_iters, 1))


@dataclasses.dataclass(frozen=True)
class Auto:
    """Cholesky up to ``AUTO_DENSE_MAX_PARTICLES`` particles, ``cg`` above (the default).

    Attributes:
      cg: the :class:`CG` used on larger cloth.
    """

    cg: CG = CG()

    def __post_init__(self):
        if not isinstance(self.cg, CG):
            raise ValueError(f"Auto cg must be a cloth.CG(...), got {self.cg!r}")


def check_linear_solver(value):
    """A ``Cholesky``, ``CG`` or ``Auto`` (``"auto"`` is ``Auto()``); ``ValueError`` naming the value otherwise."""
    if isinstance(value, str) and value == "auto":
        return Auto()
    if isinstance(value, (Cholesky, CG, Auto)):
        return value
    raise ValueError(f"linear_solver must be cloth.Cholesky(), cloth.CG(...), cloth.Auto(...) or 'auto', "
                     f"got {value!r}")


def resolve(linear_solver, n_particles: int):
    """The solver an ``Auto`` stands for at ``n_particles``, or ``linear_solver`` itself."""
    if isinstance(linear_solver, Auto):
        return Cholesky() if n_particles <= AUTO_DENSE_MAX_PARTICLES else linear_solver.cg
    return linear_solver
