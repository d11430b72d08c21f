"""CCD and FABRIK as fixed-length ``lax.scan`` loops with masked no-ops after convergence.

Both solvers share one driver: validate at the boundary, move the quaternion/vector
component axis to the front (``(J, 4, *B)``, ``(3, *B)``) so any batch trails and every
joint update is one elementwise fusion over the batch, then scan ``max_iters`` sweeps.
Once an element is within ``tol`` its iteration counter stops and its state is frozen
(by ``where``, or for the batched FABRIK sweep by a snapshot, see ``_loop``), so ``vmap``
and reverse-mode ``grad`` work on the whole fixed-length loop (the JAXopt pattern).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .. import _sharding
from .._dataclass import is_concrete
from .._dtype import tiny
from .._validate import check_bool, check_finite, check_int, check_tol
from . import _joints, _quat
from ._ccd import ccd_sweep, ccd_sweep_frames, locals_from_frames
from ._chain import Chain
from ._fabrik import fabrik_sweep, fabrik_sweep_lean, rotations_from_positions, straight_towards
from ._fk import fk, fk_joints
from ._implicit import implicit_rotations
from ._loop import masked_sweeps
from ._result import IKResult
from ._skeleton import Skeleton, topology
from ._symmetry import break_symmetry, break_symmetry_lists

SOLVERS = ("ccd", "fabrik", "lm")


@functools.partial(jax.jit, static_argnames=("kind", "max_iters", "unroll", "trace", "early_exit"))
def _run(offsets, target, local0, tol, *, kind, max_iters, unroll, trace, early_exit=False):
    """The solver on component-first arrays: ``target (3, *B)``, ``local0 (J, 4, *B)``
    or ``(J, 4)`` (one start pose for the whole batch).

    Unrolled (batches): per-joint lists; a shared start pose goes through FK once, and
    the sweeps are the lean batched ones (``fabrik_sweep_lean``, ``ccd_sweep_frames``).
    Rolled (single targets, long chains): stacked ``(J, C, *B)`` arrays in a
    ``fori_loop`` over joints.

    Returns an ``IKResult`` in the component-first layout: ``rotations (J, 4, *B)``,
    ``positions (J, 3, *B)``, ``(*B)`` error, iterations, converged and reachable, and
    the ``(max_iters, *B)`` trace or ``None``.
    """
    J = local0.shape[0]
    B = target.shape[1:]
    dtype = local0.dtype
    tgt = _quat.unstack(target)
    root = tuple(jnp.broadcast_to(c, B) for c in _quat.unstack(offsets[0]))
    lengths = jnp.sqrt(jnp.sum(offsets[1:] ** 2, axis=-1))
    reach = jnp.sum(lengths)
    reachable = _quat.safe_norm(_quat.sub(tgt, root)) <= reach

    if unroll:
        own = local0.shape[2:]  # () for a shared start pose
        L0 = [_quat.renormalize(_quat.unstack(local0[i])) for i in range(J)]
        P0, G0 = fk_joints(offsets, L0, own, unroll=True)
        err0 = _quat.safe_norm(_quat.sub(P0[J - 1], tgt))
        done0 = err0 <= tol
        L0, P0, G0 = break_symmetry_lists(L0, P0, G0, tgt, reach, done0)
    else:
        local0 = jnp.broadcast_to(local0.reshape(local0.shape + (1,) * (len(B) + 2 - local0.ndim)), (J, 4) + B)
        local0 = _quat.stack(_quat.renormalize(_quat.unstack(local0, axis=1)), axis=1)

        def fk(local_stacked):
            P, G = fk_joints(offsets, _joints.split(local_stacked, False), B, unroll=False)
            return _joints.stack(P), _joints.stack(G)

        P0, G0 = fk(local0)
        err0 = _quat.safe_norm(_quat.sub(_quat.unstack(P0[J - 1]), tgt))
        done0 = err0 <= tol
        local0 = break_symmetry(local0, P0, G0, tgt, reach, done0, B)
        P0, G0 = fk(local0)
        L0 = local0

    def batched(v):  # a loop carry needs the full batch shape
        return tuple(jnp.broadcast_to(c, B) for c in v)

    iters0 = jnp.zeros(B, jnp.int32)
    if kind == "ccd" and unroll:
        state0 = [batched(g) for g in G0]

        def sweep(frames):
            return ccd_sweep_frames(offsets, tgt, frames, root)
    elif kind == "ccd":
        state0 = (L0, P0, G0)

        def sweep(state):
            new = ccd_sweep(offsets, tgt, *state, B, unroll=False)
            return new, _quat.sqnorm(_quat.sub(_joints.get(new[1], J - 1), tgt))
    else:
        # An unreachable target is answered by the straight line towards it: one sweep,
        # final.  Those elements start the loop done, with that sweep counted.  Where two
        # joints coincide, a bone takes one direction per chain, perpendicular to the rest
        # chain (as the tree solver's fixed one): a per-target direction would be three
        # more arrays read by every joint update of the batched sweep.
        fallback = _quat.perpendicular(_quat.unstack(jnp.sum(offsets[1:], axis=0)))
        straight = straight_towards(root, tgt, lengths, fallback)
        jump = ~reachable & ~done0
        err0 = jnp.where(jump, _quat.safe_norm(_quat.sub(straight[J - 1], tgt)), err0)
        iters0 = jump.astype(jnp.int32)
        done0 = done0 | ~reachable
        if unroll:  # the lean batched sweep on joints 1..J-1 (the root never moves)
            state0 = [batched(_quat.where(jump, st, p)) for st, p in zip(straight[1:], P0[1:])]
            bias = _quat.scale(tiny(dtype), fallback)

            def sweep(state):
                new = fabrik_sweep_lean(state, tgt, root, lengths, bias)
                return new, _quat.sqnorm(_quat.sub(new[-1], tgt))
        else:
            state0 = jnp.where(jump, _joints.stack(straight), P0)

            def sweep(state):
                new = fabrik_sweep(state, tgt, root, lengths, fallback, unroll=False)
                return new, _quat.sqnorm(_quat.sub(_joints.get(new, J - 1), tgt))

    # The lean FABRIK sweep keeps going on finished elements and returns a snapshot (one
    # select per sweep off the sweep's chain: 2.42 -> 2.93 M solves/s on the benchmark's
    # 100k targets); CCD's frames sweep ran slower that way (0.58 -> 0.47) and keeps ``where``.
    freeze = "snapshot" if kind == "fabrik" and unroll else "where"
    state, iters, errs = masked_sweeps(sweep, state0, err0, iters0, jnp.broadcast_to(done0, B), tol,
                                       max_iters=max_iters, trace=trace, early_exit=early_exit, freeze=freeze)

    if kind == "ccd" and unroll:
        local = [batched(q) for q in locals_from_frames(state)]
    elif kind == "ccd":
        local = state[0]
    else:
        positions = [root] + list(state) if unroll else state
        local = rotations_from_positions(offsets, L0, positions, B, unroll=unroll)
        if unroll:
            local = [batched(q) for q in local]
    P, _ = fk_joints(offsets, local, B, unroll=unroll)
    err = _quat.safe_norm(_quat.sub(_joints.get(P, J - 1), tgt))
    return IKResult(rotations=_joints.stack(local).astype(dtype), positions=_joints.stack(P), error=err,
                    iterations=iters, converged=err <= tol, reachable=reachable, trace=errs)


def _check_target_and_rotations(chain, target, rotations):
    J = chain.num_joints
    if target.shape[-1:] != (3,):
        raise ValueError(f"target must have shape (..., 3), got {target.shape}")
    if rotations.shape[-2:] != (J, 4):
        raise ValueError(f"rotations must have shape (..., {J}, 4) for this chain, got {rotations.shape}")
    if is_concrete(target):
        check_finite("target", target)
    check_start_rotations(rotations)


def check_start_rotations(rotations):
    """Start rotations must be finite and non-zero (checked when concrete, i.e. outside ``jit``)."""
    if is_concrete(rotations):
        r = check_finite("rotations", rotations)
        if np.any(np.linalg.norm(r, axis=-1) < 1e-6):
            raise ValueError("rotations contain a zero quaternion; use (1, 0, 0, 0) for no rotation")


def check_settings(chain, solver, max_iters, tol):
    """Boundary checks shared by every IK entry point (raise before tracing)."""
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
    if not isinstance(chain, (Chain, Skeleton)):
        raise TypeError(f"chain must be a jaxsim.ik.Chain or Skeleton, got {type(chain).__name__}")
    check_int("max_iters", max_iters, 1)
    check_tol("tol", tol)


def _solve(kind, chain, target, rotations, *, max_iters, tol, trace, unroll, early_exit=False, implicit_diff=False,
           sharded=False):
    check_settings(chain, kind, max_iters, tol)
    for name, flag in (("trace", trace), ("early_exit", early_exit), ("implicit_diff", implicit_diff)):
        check_bool(name, flag)
    if unroll is not None:
        check_bool("unroll", unroll)
    if sharded is not None:
        check_bool("sharded", sharded)
    dtype = chain.offsets.dtype
    target = target_in = jnp.asarray(target, dtype)
    rotations = chain.rest_rotations() if rotations is None else jnp.asarray(rotations, dtype)
    _check_target_and_rotations(chain, target, rotations)
    rotations = _quat.unit_quaternions(rotations)  # under jit: a zero quaternion is the identity, never NaN
    batch = jnp.broadcast_shapes(target.shape[:-1], rotations.shape[:-2])
    target = jnp.broadcast_to(target, batch + (3,))
    shared = rotations.ndim == 2  # one start pose for the whole batch: FK of it once
    full_rotations = jnp.broadcast_to(rotations, batch + rotations.shape[-2:])
    n = int(np.prod(batch))
    mesh = _sharding.batch_mesh(sharded, n) if batch else None
    if mesh is not None:  # split the flattened batch over the local devices
        (tflat, rflat), pad = _sharding.shard_leading((target.reshape(n, 3), full_rotations.reshape((n,) + rotations.shape[-2:])), mesh, n)
        res = _solve(kind, chain, tflat, rflat, max_iters=max_iters, tol=tol, trace=trace, unroll=unroll,
                     early_exit=early_exit, implicit_diff=implicit_diff, sharded=False)
        res = _sharding.unpad(res, pad)
        return jax.tree_util.tree_map(lambda a: a.reshape(batch + a.shape[1:]), res)
    J = chain.num_joints
    offsets = chain.offsets
    if not shared:
        rotations = full_rotations
    if implicit_diff:  # the sweeps are not differentiated; see _implicit
        offsets, target, rotations = (lax.stop_gradient(a) for a in (offsets, target, rotations))
    res = _run(
        offsets,
        jnp.moveaxis(target, -1, 0),
        jnp.moveaxis(rotations, (-2, -1), (0, 1)),  # (J, 4) when shared, else (J, 4, *B)
        jnp.asarray(tol, dtype),
        kind=kind,
        max_iters=int(max_iters),
        unroll=_joints.unrolled(J, unroll, int(np.prod(batch))),
        trace=bool(trace),
        early_exit=bool(early_exit),
    )
    local, P = jnp.moveaxis(res.rotations, (0, 1), (-2, -1)), jnp.moveaxis(res.positions, (0, 1), (-2, -1))
    err, iters, conv, reachable, errs = res.error, res.iterations, res.converged, res.reachable, res.trace
    if implicit_diff:
        topo = topology((-1,) + tuple(range(J - 1)), (J - 1,))
        ift = functools.partial(implicit_rotations, topo)
        for _ in batch:
            ift = jax.vmap(ift, in_axes=(0, None, 0, None, 0))
        tgt = jnp.broadcast_to(jnp.asarray(target_in, dtype), batch + (3,))
        local = ift(local, chain.offsets, tgt[..., None, :], jnp.ones((1,), dtype), reachable)
        P = fk(chain, local).positions
        err = jnp.sqrt(jnp.sum((P[..., -1, :] - tgt) ** 2, axis=-1))
    return IKResult(
        rotations=local,
        positions=P,
        error=err,
        iterations=iters,
        converged=conv,
        reachable=reachable,
        trace=None if errs is None else jnp.moveaxis(errs, 0, -1),
    )

