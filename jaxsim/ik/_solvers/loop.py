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

from ..._dataclass import pytree_dataclass
from ..._geometry import quat as _quat


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


def _swept(out):
    """``(state, sq_error, stop)`` of a sweep's ``(state, sq_error)`` or ``(state, sq_error, stop)``."""
    return (out[0], out[1], out[2]) if len(out) == 3 else (out[0], out[1], None)


def masked_sweeps(sweep, state0, err0, iters0, done0, tol, *, max_iters, trace, early_exit, freeze="where",
                  keep_best=False):
    """Run up to ``max_iters`` sweeps.

    Args:
      sweep: ``state -> (new_state, sq_error)``, ``sq_error`` of batch shape ``B``: the
        squared error (the worst effector's) of the pose after the sweep; or
        ``(new_state, sq_error, stop)``, with ``stop`` a ``B``-shaped bool that ends an
        element short of ``tol`` too (LM at a stationary point).
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
        new, e2, stop = _swept(sweep(state))
        err = c.err
        if trace:  # the error is carried only when a per-sweep trace is asked for
            err = jnp.where(c.done, err, _quat.safe_sqrt(e2))
        hit = ~c.done & (e2 <= tol2)
        if stop is not None:  # the sweep's own test (LM: a stationary point) ends it too
            hit = hit | (~c.done & stop)
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


@pytree_dataclass
class _QueueCarry:
    """What :func:`refill_sweeps` carries: ``W`` lanes working through a queue of ``N`` items.

    Attributes:
      lane: ``(W,)`` int32, the item each lane works on (``N``: idle).
      items: the lanes' items (a pytree, leading axis ``W``).
      iters: ``(W,)`` int32, sweeps of each lane's current start; total: ``(W,)`` int32, of all its starts.
      seed: ``(W,)`` int32, which start of its item each lane is on.
      best, best_e2: ``seeds > 1`` only (else ``None``): each lane's best finished start so far
        and its squared error (``inf`` before the first).
      mark: with ``stall`` only (else ``None``): each lane's squared error at its last stall check.
      wait: ``seeds > 1`` only (else ``None``): ``(W,)`` bool, the lanes whose next start is still
        to be computed (they sweep no more until it is).
      head: ``()`` int32, queue entries handed out so far.
      out: every item's result (leading axis ``N``); out_iters: ``(N,)`` int32.
    """

    lane: jax.Array
    items: Any
    iters: jax.Array
    total: jax.Array
    seed: jax.Array
    best: Any
    best_e2: jax.Array | None
    mark: jax.Array | None
    wait: jax.Array | None
    head: jax.Array
    out: Any
    out_iters: jax.Array


def _rows_where(c, a, b):
    """``jnp.where`` per leading row: ``c (W,)`` against leaves ``(W, ...)``."""
    return jax.tree_util.tree_map(lambda x, y: jnp.where(c.reshape(c.shape + (1,) * (x.ndim - 1)), x, y), a, b)


#: With ``seeds > 1``, at most ``lanes // RESTART_SHARE`` lanes get their next start per sweep
#: (the rest wait a sweep): a restart (the limited humanoid's: projection, root alignment,
#: limb start, three FK passes) costs about three sweeps of all lanes, and computing it for
#: every lane whenever one needed it was most of ``seeds=8``'s time (docs/notebook.md).
RESTART_SHARE = 8


def refill_sweeps(sweep, items0, e2_0, tol, *, max_iters, lanes, seeds=1, restart=None, stall=None):
    """:func:`masked_sweeps` with ``early_exit`` on a flat batch, as a work queue: ``lanes``
    lanes sweep at once, and a lane whose item meets ``tol`` (or reaches ``max_iters``)
    hands it back and takes the next item not yet started.  The loop's sweeps then number
    about ``sum(iterations) / lanes``, where a batch that stops only when its slowest item
    is done sweeps every item ``max(iterations)`` times.  Each item gets the sweeps, state
    and count that :func:`masked_sweeps` gives it.

    With ``seeds > 1`` an item that ends a start unconverged is started again, in the same
    lane, from ``restart(items, k)`` for ``k = 1, ..., seeds - 1`` in turn, until a start
    converges; it keeps the first start that converged, else the one of least error, and
    its count is the sweeps of every start it ran.  Extra starts cost only where the first fails.

    Args:
      sweep: ``items (W, ...) -> (items, sq_error (W,))`` (or with a third ``stop (W,)``,
        as for :func:`masked_sweeps`: a start that stops short of ``tol`` goes on to the next
        seed), lane by lane (vmapped); an item carries its problem data as well as its state.
      items0: the start items, a pytree with leading axis ``N``; e2_0: ``(N,)`` their squared errors.
      tol: scalar tolerance; max_iters (per start), lanes (``<= N``), seeds: static.
      restart: ``(items (W, ...), k (W,)) -> items``, the items started afresh from start ``k``.
      stall: ``seeds > 1`` only: ``(every, ratio)`` (static) ends a start early whose squared
        error, checked every ``every`` sweeps, is above ``ratio`` times its last check's; or ``None``.

    Returns:
      ``(items (N, ...), iterations (N,))``.
    """
    N = e2_0.shape[0]
    tol2 = tol * tol
    done0 = e2_0 <= tol2
    queue = jnp.argsort(done0, stable=True).astype(jnp.int32)  # the items to solve first, in order
    pending = N - jnp.sum(done0, dtype=jnp.int32)
    first = jnp.arange(lanes, dtype=jnp.int32)
    lane0 = jnp.where(first < pending, queue[first], N)
    multi = seeds > 1
    inf = jnp.full((lanes,), jnp.inf, jnp.result_type(e2_0))

    def take(idx):
        return jax.tree_util.tree_map(lambda a: a[jnp.minimum(idx, N - 1)], items0)

    slots = max(1, lanes // RESTART_SHARE)  # restarts computed per sweep, at most

    def restart_some(items, wait, seed):
        """The first ``slots`` waiting lanes started afresh: ``(items, wait)``."""
        idx = jnp.argsort((~wait).astype(jnp.int32), stable=True)[:slots]
        sel = wait[idx]
        sub = jax.tree_util.tree_map(lambda a: a[idx], items)
        fresh = _rows_where(sel, restart(sub, seed[idx]), sub)
        return jax.tree_util.tree_map(lambda a, f: a.at[idx].set(f), items, fresh), wait.at[idx].set(False)

    def body(c: _QueueCarry) -> _QueueCarry:
        active = c.lane < N if c.wait is None else (c.lane < N) & ~c.wait
        new, e2, stop = _swept(sweep(c.items))
        iters, total = c.iters + active.astype(jnp.int32), c.total + active.astype(jnp.int32)
        hit = e2 <= tol2
        ended = active & (hit | (iters >= max_iters) | (False if stop is None else stop))
        mark = c.mark
        if mark is not None:  # a start whose error has not fallen enough in `every` sweeps ends
            every, ratio = stall
            check = active & (iters % every == 0)
            ended = ended | (check & (e2 > ratio * mark))
            mark = jnp.where(check, e2, mark)
        result, best, best_e2, again = new, c.best, c.best_e2, jnp.zeros_like(ended)
        if multi:  # a start that ended unconverged: the next start, or the best of them
            better = ended & (e2 < best_e2)
            best, best_e2 = _rows_where(better, new, best), jnp.where(better, e2, best_e2)
            again = ended & ~hit & (c.seed + 1 < seeds)
            result = _rows_where(hit, new, best)
        fin = ended & ~again
        slot = jnp.where(fin, c.lane, N)  # out of range: dropped
        out = jax.tree_util.tree_map(lambda o, x: o.at[slot].set(x, mode="drop"), c.out, result)
        out_iters = c.out_iters.at[slot].set(total, mode="drop")
        src = c.head + jnp.cumsum(fin, dtype=jnp.int32) - 1
        refill = fin & (src < pending)
        nxt = queue[jnp.clip(src, 0, N - 1)]
        lane = jnp.where(refill, nxt, jnp.where(fin, N, c.lane))
        items = _rows_where(active, new, c.items)
        seed, wait = c.seed, c.wait
        if multi:
            seed = jnp.where(again, seed + 1, jnp.where(fin, 0, seed))
            wait = wait | again
            items, wait = lax.cond(jnp.any(wait), restart_some, lambda i, w, s: (i, w), items, wait, seed)
            best_e2 = jnp.where(fin, jnp.inf, best_e2)
            if mark is not None:
                mark = jnp.where(ended, jnp.inf, mark)
        items = _rows_where(refill, take(nxt), items)
        return _QueueCarry(lane=lane, items=items, iters=jnp.where(ended, 0, iters), total=jnp.where(fin, 0, total),
                           seed=seed, best=best, best_e2=best_e2, mark=mark, wait=wait,
                           head=c.head + jnp.sum(fin, dtype=jnp.int32),
                           out=out, out_iters=out_iters)

    zeros = jnp.zeros((lanes,), jnp.int32)
    start = take(lane0)
    c0 = _QueueCarry(lane=lane0, items=start, iters=zeros, total=zeros, seed=zeros, best=start if multi else None,
                     best_e2=inf if multi else None, mark=inf if multi and stall is not None else None,
                     wait=jnp.zeros((lanes,), bool) if multi else None,
                     head=jnp.asarray(lanes, jnp.int32), out=items0,
                     out_iters=jnp.zeros((N,), jnp.int32))
    c = lax.while_loop(lambda c: jnp.any(c.lane < N), body, c0)
    return c.out, c.out_iters
