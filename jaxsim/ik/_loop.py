"""The sweep loop shared by every IK solver: a fixed-length ``lax.scan`` whose sweeps are
masked no-ops once an element is done (the JAXopt pattern), or a ``lax.while_loop`` that
stops when the whole batch is done.  A finished element keeps its state either by a
``where`` at every sweep or by a snapshot taken at the sweep after it finished."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import jax
import jax.numpy as jnp
from jax import lax

from .._dataclass import pytree_dataclass
from .._geometry import quat as _quat


@pytree_dataclass
class _SweepCarry:
    """What the sweep loop carries, every leaf of batch shape ``B``.

    Attributes:
      state: the solver's state (a pytree) after the sweeps so far.
      snap: ``freeze="snapshot"`` only (else ``None``): each finished element's state.
      pend: ``freeze="snapshot"`` only: ``state`` met ``tol`` at the sweep just run.
      err: the error after the sweeps so far (only with a trace, else ``None``).
      iters: ``int32`` sweeps counted.
      done: ``bool``, met ``tol``.
      best: ``keep_best`` only (else ``None``): the state of lowest error so far, the
        start included.
      best_e2: ``keep_best`` only: its squared error.
    """

    state: Any
    snap: Any
    pend: jax.Array | None
    err: jax.Array | None
    iters: jax.Array
    done: jax.Array
    best: Any = None
    best_e2: jax.Array | None = None


@dataclasses.dataclass(frozen=True)
class SweepPlan:
    """One algorithm's sweeps on one problem, as an algorithm module lays them out.

    Attributes:
      state0: the start state (a pytree of ``B``-shaped arrays).
      sweep: ``state -> (state, sq_error)``, as for :func:`masked_sweeps`.
      rotations: ``final state -> J`` local rotations (a list of quaternion tuples, or
        a stacked ``(J, 4, *B)`` array on a rolled chain).
      err0, iters0, done0: ``B``-shaped start error, sweep count and done flags.
      freeze: ``"where"`` or ``"snapshot"`` (see :func:`masked_sweeps`).
      keep_best: return the best state visited (see :func:`masked_sweeps`).
    """

    state0: Any
    sweep: Callable
    rotations: Callable
    err0: Any
    iters0: Any
    done0: Any
    freeze: str = "where"
    keep_best: bool = False


def run_plan(plan: SweepPlan, tol, *, max_iters, trace, early_exit):
    """``(local rotations, iterations, trace)`` of :func:`masked_sweeps` on ``plan``."""
    B = jnp.shape(plan.iters0)
    state, iters, errs = masked_sweeps(plan.sweep, plan.state0, plan.err0, plan.iters0,
                                       jnp.broadcast_to(plan.done0, B), tol, max_iters=max_iters, trace=trace,
                                       early_exit=early_exit, freeze=plan.freeze, keep_best=plan.keep_best)
    return plan.rotations(state), iters, errs


def masked_sweeps(sweep, state0, err0, iters0, done0, tol, *, max_iters, trace, early_exit, freeze="where",
                  keep_best=False):
    """Run up to ``max_iters`` sweeps.

    Args:
      sweep: ``state -> (new_state, sq_error)``, ``sq_error`` of batch shape ``B``: the
        squared error (the worst effector's) of the pose after the sweep.
      state0: the start state (a pytree of ``B``-shaped arrays).
      err0, iters0, done0: ``B``-shaped start error, sweep count and done flags.
      tol: scalar tolerance on the error.
      max_iters, trace, early_exit: static; ``trace`` carries the error and returns it
        per sweep, ``early_exit`` uses the while loop (forward-mode differentiable only).
      freeze: static, how a finished element keeps its state.  ``"where"`` selects the
        old state over the new one at every sweep.  ``"snapshot"`` lets every element
        keep sweeping and copies the state into a snapshot at the sweep after the one
        that met ``tol`` (the flag is then a loop carry, not recomputed from this sweep's
        output inside every select), and returns the snapshot for finished elements.
        Same states and counts; the sweep's own chain of operations carries no select,
        which lets XLA keep it in fewer, simpler fusions (``benchmarks/ik_throughput.py``).
        The sweep must stay finite on a finished element's later states.
      keep_best: static; also carry the state of lowest error seen (the start state
        included) and return it instead of the last one.  For sweeps that are not
        monotone (FABRIK with limits: the projection onto the limits can undo a
        sweep's progress), so that a solve never returns a pose worse than its start.

    Returns:
      ``(state, iterations, trace)``; ``trace`` is ``(max_iters, *B)`` or ``None``
      (the error after each sweep, so with ``keep_best`` its last entry may exceed the
      returned state's).  An element's counter stops, and its state is frozen, at the
      first sweep whose error is within ``tol``.
    """
    B = jnp.shape(done0)
    tol2 = tol * tol
    snapshot = freeze == "snapshot"

    def body(c, _):
        snap, state = c.snap, c.state
        if snapshot:  # ``pend``: the state met ``tol`` at the previous sweep
            snap = _quat.where(c.pend, state, snap)
        new, e2 = sweep(state)
        err = c.err
        if trace:  # the error is carried only when a per-sweep trace is asked for
            err = jnp.where(c.done, err, _quat.safe_sqrt(e2))
        hit = ~c.done & (e2 <= tol2)
        best, best_e2 = c.best, c.best_e2
        if keep_best:
            better = ~c.done & (e2 < best_e2)
            best, best_e2 = _quat.where(better, new, best), jnp.where(better, e2, best_e2)
        c = _SweepCarry(state=new if snapshot else _quat.where(c.done, state, new), snap=snap,
                        pend=hit if snapshot else None, err=err,
                        iters=c.iters + (~c.done).astype(jnp.int32), done=c.done | hit, best=best, best_e2=best_e2)
        return c, (err if trace else None)

    def finish(c):
        state = c.state
        if snapshot:
            state = _quat.where(c.done, _quat.where(c.pend, state, c.snap), state)
        if keep_best:
            state = _quat.where(c.done, state, c.best)
        return state, c.iters

    carry0 = _SweepCarry(state=state0, snap=state0 if snapshot else None,
                         pend=jnp.zeros(B, bool) if snapshot else None,
                         err=jnp.broadcast_to(err0, B) if trace else None, iters=iters0, done=done0,
                         best=state0 if keep_best else None,
                         best_e2=jnp.broadcast_to(err0 * err0, B) if keep_best else None)
    if not early_exit:
        carry, errs = lax.scan(body, carry0, None, length=max_iters)
        return (*finish(carry), errs)
    buf0 = jnp.zeros((max_iters,) + B, jnp.result_type(err0)) if trace else None

    def w_body(c):
        k, carry, buf = c
        carry, e = body(carry, None)
        if trace:
            buf = lax.dynamic_update_index_in_dim(buf, e, k, 0)
        return k + 1, carry, buf

    def w_cond(c):
        return (c[0] < max_iters) & ~jnp.all(c[1].done)

    k, carry, buf = lax.while_loop(w_cond, w_body, (0, carry0, buf0))
    state, iters = finish(carry)
    errs = None
    if trace:
        rows = jnp.arange(max_iters).reshape((max_iters,) + (1,) * len(B))
        errs = jnp.where(rows < k, buf, carry.err)
    return state, iters, errs
