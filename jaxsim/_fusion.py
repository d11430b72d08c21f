"""Steering XLA:CPU's fusion: an array that its consumers read instead of recomputing."""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax

#: ``False`` returns ``x`` itself from :func:`materialized`, read when a function is traced:
#: ``benchmarks/cloth_fusion.py`` compiles the cloth step both ways and times them in
#: one process.
ENABLED = True


def materialized(x):
    """``x`` unchanged, written to memory once before its consumers run.

    XLA fuses an elementwise producer into each consumer and recomputes it there.  Where
    the consumer reads every element several times (the grid operator's padded slices
    read each spring's value at both of its ends, and every component of a particle's
    sum recomputes the spring's length and force), the recomputation costs more than
    writing the array once.  ``lax.optimization_barrier`` does not prevent it on CPU
    (the compiled program holds no barrier), but a conditional's result is a buffer of
    its own, so ``x`` comes back through ``lax.cond``.  Its predicate asks whether the
    first element is NaN, and that branch fills the array with NaN: a NaN there spreads
    to every entry (callers already treat any NaN as a failed evaluation), and nothing
    else changes.  Under ``vmap`` the conditional becomes a ``select`` with the same
    values.

    Args:
      x: a floating array (any shape); an empty one is returned as it is.
    """
    if x.size == 0 or not ENABLED:
        return x
    first = x.reshape(-1)[0]
    return lax.cond(jnp.isnan(first), lambda: jnp.full_like(x, jnp.nan), lambda: x)
