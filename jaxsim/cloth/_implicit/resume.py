"""What a rollout reads of the previous one's ``(states, infos)`` (``rollout(resume=)``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..._dataclass import pytree_dataclass
from .bdf2 import Before
from .substeps import Memory


@pytree_dataclass
class Resume:
    """The last steps of a previous rollout, all that the next one reads of it (so the
    compiled rollout does not depend on the previous one's length).

    Attributes:
      v: ``(K, N, 3)`` its last ``K = min(T, 3)`` velocities (m/s).
      converged: ``()`` bool, its last step converged.
      newton_iters: ``()`` int32, that step's Newton iterations.
      x_prev: ``(N, 3)`` BDF2 only: the positions one step before its last state (m), or
        ``None`` (another integrator, or a one-step rollout).
      whole: ``()`` bool, BDF2 only: its last step was taken, in one substep (``None``
        where ``x_prev`` is).
      memory: the adaptive substeps' memory after its last step (``StepInfo.memory``), or
        ``None`` (it had none).
    """

    v: jax.Array
    converged: jax.Array
    newton_iters: jax.Array
    x_prev: jax.Array | None = None
    whole: jax.Array | None = None
    memory: Memory | None = None

    def substep_memory(self, depth: int) -> Memory:
        """The memory the resumed rollout's first step starts from, with adaptive substeps
        to ``depth`` levels: the previous rollout's (its level capped at ``depth``), or a
        first step's."""
        if self.memory is None:
            return Memory.start()
        return Memory(jnp.minimum(self.memory.level, depth), self.memory.trying, self.memory.wait,
                      self.memory.patience, self.memory.cost)

    def before(self, x, v, dt) -> Before:
        """BDF2's memory for the resumed rollout's first step from ``(x, v)`` (``(N, 3)``),
        of ``dt`` seconds: the previous rollout's last step, taken as one of ``dt``, where
        it was taken whole (its memory is then exactly the one a longer rollout carries);
        otherwise none, so the first step is backward Euler (a step taken in substeps
        remembers its last substep, which ``states`` does not hold)."""
        if self.x_prev is None:
            return Before.none(x, v)
        return Before(self.x_prev, self.v[-2], jnp.where(self.whole, jnp.asarray(dt, x.dtype), 0.0))
