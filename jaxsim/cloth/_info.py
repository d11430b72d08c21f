"""Per-step diagnostics of the cloth steppers."""

from __future__ import annotations

import jax

from .._dataclass import pytree_dataclass
from ._implicit.trace import NewtonTrace
from ._implicit.substeps import Memory  # noqa: F401 (the annotation)


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
        solves backward Euler to that accuracy; with substeps, every substep does);
        explicit: same as ``stable``.
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
      substeps: implicit: the substeps the step took (1 unless Newton did not converge
        on the whole step, ``ImplicitEuler.max_substep_depth``; 0 when the step was not
        taken); explicit: ``ExplicitEuler.substeps``.  With substeps ``newton_iters``,
        ``cg_iters`` and ``backtracks`` are summed over every attempt (those retried as
        halves too), ``rel_grad``, ``grad_norm`` and ``cond_bound`` are the largest over
        the substeps, ``step_size``, ``residual`` and ``trace`` are the last attempt's.
      trace: ``NewtonTrace`` of the step's Newton iterations with
        ``ImplicitEuler(trace=True)``, else ``None``.
      pair_overflow: with ``Cloth.self_contact``: a motion had more self-contact pairs
        than ``Cloth.self_contact_pairs`` slots (an iteration that met it was not taken,
        so the step is retried in substeps or not converged); ``None`` without self-contact.
      memory: with adaptive substeps, the memory a ``rollout``'s next step starts from
        (``_implicit.substeps.Memory``): ``memory.level``, the level it first attempts
        (``dt / 2^level``: the coarsest substep this step took, or one coarser after a
        step whose attempts all converged and no wait is pending; 0 after a step taken
        whole), ``memory.wait``, the steps before a coarser level is tried again, and
        ``memory.patience``.  ``None`` without substeps.
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
    substeps: jax.Array
    trace: NewtonTrace | None = None
    pair_overflow: jax.Array | None = None
    memory: "Memory | None" = None
