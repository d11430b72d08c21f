"""The sweep loop shared by every IK solver: a fixed-length ``lax.scan`` whose sweeps are
masked no-ops once an element is done (the JAXopt pattern), or a ``lax.while_loop`` that
stops when the whole batch is done."""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax

from . import _quat


def masked_sweeps(sweep, state0, err0, iters0, done0, tol, *, max_iters, trace, early_exit):
    """Run up to ``max_iters`` sweeps.

    Args:
      sweep: ``state -> (new_state, sq_error)``, ``sq_error`` of batch shape ``B``: the
        squared error (the worst effector's) of the pose after the sweep.
      state0: the start state (a pytree of ``B``-shaped arrays).
      err0, iters0, done0: ``B``-shaped start error, sweep count and done flags.
      tol: scalar tolerance on the error.
      max_iters, trace, early_exit: static; ``trace`` carries the error and returns it
        per sweep, ``early_exit`` uses the while loop (forward-mode differentiable only).

    Returns:
      ``(state, iterations, trace)``; ``trace`` is ``(max_iters, *B)`` or ``None``.
      An element's counter stops, and its state is frozen, at the first sweep whose
      error is within ``tol``.
    """
    B = jnp.shape(done0)
    tol2 = tol * tol

    def body(carry, _):
        state, err, iters, done = carry
        new, e2 = sweep(state)
        state = _quat.where(done, state, new)
        iters = iters + (~done).astype(jnp.int32)
        if trace:  # the error is carried only when a per-sweep trace is asked for
            err = jnp.where(done, err, _quat.safe_sqrt(e2))
        done = done | (e2 <= tol2)
        return (state, err, iters, done), (err if trace else None)

    carry0 = (state0, jnp.broadcast_to(err0, B) if trace else None, iters0, done0)
    if not early_exit:
        (state, _, iters, _), errs = lax.scan(body, carry0, None, length=max_iters)
        return state, iters, errs
    buf0 = jnp.zeros((max_iters,) + B, jnp.result_type(err0)) if trace else None

    def w_body(c):
        k, carry, buf = c
        carry, e = body(carry, None)
        if trace:
            buf = lax.dynamic_update_index_in_dim(buf, e, k, 0)
        return k + 1, carry, buf

    def w_cond(c):
        return (c[0] < max_iters) & ~jnp.all(c[1][3])

    k, (state, err_last, iters, _), buf = lax.while_loop(w_cond, w_body, (0, carry0, buf0))
    errs = None
    if trace:
        rows = jnp.arange(max_iters).reshape((max_iters,) + (1,) * len(B))
        errs = jnp.where(rows < k, buf, err_last)
    return state, iters, errs
