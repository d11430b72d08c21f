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


def materialized_rows(vectors):
    """A list of component tuples (vectors or quaternions over one batch shape, or none),
    written to memory once: one :func:`materialized` array per batch shape.

    Where a chain of tuples feeds many consumers (the FK chain of a skeleton's start
    pose, read by every branch test and broadcast of ``ik._kernel.bent_start``), XLA fuses
    the whole chain into each of them: the humanoid's ``bent_start`` compiled in 10.7 s
    (78,624 lines of optimised HLO), 6.0 s (23,858 lines) with its FK written once;
    this helper gives 23,165 lines and 318 fusions (docs/notebook.md).
    """
    out, shapes = list(vectors), [jnp.broadcast_shapes(*map(jnp.shape, v)) for v in vectors]
    for shape in dict.fromkeys(shapes):  # e.g. the root's position: no batch axis
        ids = [i for i, s in enumerate(shapes) if s == shape]
        A = materialized(jnp.stack([jnp.stack(jnp.broadcast_arrays(*vectors[i])) for i in ids]))
        for row, i in enumerate(ids):
            out[i] = tuple(A[row, k] for k in range(A.shape[1]))
    return out
