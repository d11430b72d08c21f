"""IK solver settings: small frozen, hashable objects, like ``cloth.ImplicitEuler``; the
driver dispatches on their type (``kernel.PLANS``, ``solve``)."""

from __future__ import annotations

import dataclasses
import jax

from ..._validate import check_bool, check_int, check_real, check_tol

#: ``max_iters`` and ``tol`` when neither the call nor a settings object gives them.
DEFAULT_MAX_ITERS = 100
DEFAULT_TOL = 1e-4


@dataclasses.dataclass(frozen=True)
class _Settings:
    max_iters: int = DEFAULT_MAX_ITERS
    tol: float = DEFAULT_TOL
    _: dataclasses.KW_ONLY
    early_exit: bool | None = None
    trace: bool = False
    implicit_diff: bool = False

    def __post_init__(self):
        object.__setattr__(self, "max_iters", check_int("max_iters", self.max_iters, 1))
        check_tol("tol", self.tol)
        if not isinstance(self.tol, jax.core.Tracer):  # a traced tol (inside jit) stays as it is
            object.__setattr__(self, "tol", float(self.tol))
        for name in ("early_exit", "trace", "implicit_diff"):
            flag = getattr(self, name)
            if not (flag is None and name == "early_exit"):
                object.__setattr__(self, name, check_bool(name, flag))


@dataclasses.dataclass(frozen=True)
class _Sweeps(_Settings):
    unroll: bool | None = None

    def __post_init__(self):
        super().__post_init__()
        if self.unroll is not None:
            object.__setattr__(self, "unroll", check_bool("unroll", self.unroll))


@dataclasses.dataclass(frozen=True)
class FABRIK(_Sweeps):
    """FABRIK settings (Aristidou & Lasenby 2011; §4.2 on trees).

    Attributes:
      max_iters: sweeps scanned (static; a new value recompiles).
      tol: converged when every effector is within ``tol`` of its target (scene units).
      early_exit: ``None`` (the default): the sweeps stop once every element of the
        batch is done (a ``lax.while_loop``, or LM's work queue), and where the call is
        differentiated (``jax.grad``, ``jax.jvp``, even through a ``jit``) the derivative
        and the value come from the fixed-length ``lax.scan`` of masked no-ops, which JAX
        can reverse-differentiate (a ``custom_jvp``).  ``True``: always the early loop
        (forward mode only; ``jax.grad`` raises).  ``False``: always the scan.
      trace: also return ``trace (..., max_iters)``, the worst effector's error after
        each sweep (off by default to save memory).
      implicit_diff: differentiate the returned solution by the implicit function
        theorem (``ik._driver.implicit``) instead of through the sweeps: no memory per
        sweep, least-change rotations derivative; with limits the bounds the solution
        sits on are held.
      unroll: chains: unroll the loop over joints (default: ``J <= 16`` and a batch of
        >= 256), else a ``fori_loop``.  Other trees are unrolled over their static joints.
    """


@dataclasses.dataclass(frozen=True)
class CCD(_Sweeps):
    """Cyclic coordinate descent settings; on trees each joint takes Horn's (1987) best rotation.

    Attributes:
      max_iters: sweeps scanned (static; a new value recompiles).
      tol: converged when every effector is within ``tol`` of its target (scene units).
      early_exit, trace, implicit_diff, unroll: as for :class:`FABRIK`.
    """


@dataclasses.dataclass(frozen=True)
class LevenbergMarquardt(_Settings):
    """Damped least-squares (Levenberg–Marquardt) settings; see ``jaxsim.ik._solvers.lm``.

    Attributes:
      max_iters: iterations scanned (static; a new value recompiles); a rejected trial
        step counts as one.
      tol: converged when every effector is within ``tol`` of its target (scene units).
      damping: the starting relative damping ``lambda`` (> 0), adapted per iteration.
      seeds: starts per target set (static, >= 1): the given (or default) start and
        ``seeds - 1`` fixed poses inside the limits; the first that converges is kept
        (else the closest), and ``iterations`` counts them all (``starts``).  With
        ``early_exit`` on 128 or more sets the starts run one after another, each only
        where the earlier ones failed or stalled (``lm.run_lm``).
      early_exit, trace, implicit_diff: as for :class:`FABRIK` (``early_exit=None`` runs
        128 sets or more as the work queue).
    """

    damping: float = 1e-2
    seeds: int = 1

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "damping", check_real("damping", self.damping, minimum=0.0, strict=True))
        object.__setattr__(self, "seeds", check_int("seeds", self.seeds, 1))


_BY_NAME = {"fabrik": FABRIK, "ccd": CCD, "lm": LevenbergMarquardt}


def resolve_settings(solver, max_iters, tol) -> _Settings:
    """The settings object, given one or a name plus keywords.

    With a settings object, ``max_iters`` and ``tol`` must be left out (``None``).
    """
    if isinstance(solver, _Settings):
        if max_iters is not None or tol is not None:
            raise ValueError(f"give max_iters and tol in the settings object ({solver!r}), not beside it")
        return solver
    if not isinstance(solver, str) or solver not in _BY_NAME:
        raise ValueError(f"solver must be one of {tuple(_BY_NAME)} or a jaxsim.ik.FABRIK / CCD / "
                         f"LevenbergMarquardt object, got {solver!r}")
    return _BY_NAME[solver](DEFAULT_MAX_ITERS if max_iters is None else max_iters,
                            DEFAULT_TOL if tol is None else tol)
