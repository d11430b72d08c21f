"""The IK driver for joint trees: validate, lay the batch out last, scan masked sweeps.

A skeleton that is a chain with its last joint as the only (unweighted) effector takes
the chain path (``_solve``), so its results are the chain's; the tree sweeps reduce to
the chain's on such a skeleton (tested), but the chain kernels are the tuned ones.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._dataclass import is_concrete
from .._validate import check_finite
from . import _quat
from ._implicit import implicit_rotations
from ._loop import masked_sweeps
from ._result import IKResult
from ._symmetry import break_symmetry_tree
from ._skeleton import Skeleton, check_effectors, topology
from ._solve import check_start_rotations
from ._tree_fk import fk_tree, skeleton_fk
from ._tree_sweeps import branch_weights, ccd_tree_rotations, ccd_tree_sweep, fabrik_tree_rotations, fabrik_tree_sweep


def _batched(v, B):
    return None if v is None else tuple(jnp.broadcast_to(c, B) for c in v)


@functools.partial(jax.jit, static_argnames=("topo",))
def bent_start(offsets, targets, local0, tol, *, topo):
    """``(J, 4, *B)`` start rotations with straight branches on their targets' lines bent
    (``_symmetry.break_symmetry_tree``).  Compiled apart from the sweeps: inside the same
    program it doubles their compile time."""
    J, B = len(topo.parents), targets.shape[2:]
    L0 = [_quat.renormalize(_quat.unstack(local0[i])) for i in range(J)]
    P0, G0 = fk_tree(topo.parents, offsets, L0)
    L0 = break_symmetry_tree(topo, offsets, L0, P0, G0, [_quat.unstack(targets[k]) for k in range(targets.shape[0])],
                             tol)
    return _quat.stack([_quat.stack(_batched(q, B)) for q in L0])


@functools.partial(jax.jit, static_argnames=("topo", "kind", "max_iters", "trace", "early_exit", "bend"))
def run_tree(offsets, targets, local0, weights, tol, *, topo, kind, max_iters, trace, early_exit=False, bend=True):
    """Tree IK on component-first arrays.

    Args:
      offsets: ``(J, 3)``; targets: ``(E, 3, *B)``; local0: ``(J, 4, *B)`` or ``(J, 4)``
      (one start pose for the batch); weights: ``(E,)``; tol: scalar.
      bend: bend straight branches first (see :func:`bent_start`); False when the
        caller has done so.

    Returns:
      ``IKResult`` in the component-first layout: ``rotations (J, 4, *B)``,
      ``positions (J, 3, *B)``, ``error (E, *B)``, ``reachable (E, *B)``, ``(*B)``
      iterations and converged, ``trace (max_iters, *B)`` (the worst effector) or ``None``.
    """
    J, E = len(topo.parents), len(topo.effectors)
    B = targets.shape[2:]
    dtype = offsets.dtype
    tgt = [_quat.unstack(targets[k]) for k in range(E)]
    w = [weights[k] for k in range(E)]
    root = _batched(_quat.unstack(offsets[0]), B)
    lengths = jnp.concatenate([jnp.zeros((1,), dtype), jnp.sqrt(jnp.sum(offsets[1:] ** 2, axis=-1))])  # no sqrt(0)
    reach = [sum(lengths[j] for j in path[1:]) if len(path) > 1 else jnp.zeros((), dtype) for path in topo.path]
    reachable = jnp.stack([_quat.safe_norm(_quat.sub(t, root)) <= r for t, r in zip(tgt, reach)])
    L0 = [_quat.renormalize(_quat.unstack(local0[i])) for i in range(J)]
    P0, G0 = fk_tree(topo.parents, offsets, L0)
    if bend:  # FABRIK paper §5.4, per branch
        L0 = break_symmetry_tree(topo, offsets, L0, P0, G0, tgt, tol)
        P0, G0 = fk_tree(topo.parents, offsets, L0)
    e2 = [_quat.sqnorm(_quat.sub(P0[e], t)) for e, t in zip(topo.effectors, tgt)]
    worst0 = functools.reduce(jnp.maximum, e2)
    done0 = jnp.broadcast_to(worst0 <= tol * tol, B)
    act = set(topo.active)
    if kind == "fabrik":
        W = branch_weights(topo, w)
        fallback = (jnp.zeros((), dtype), jnp.zeros((), dtype), jnp.ones((), dtype))
        subbase = [len(c) > 1 for c in topo.active_children]
        state0 = ([_batched(P0[i], B) if i in act else None for i in range(J)],
                  [_batched(G0[i], B) if subbase[i] else None for i in range(J)])

        def sweep(state):
            P, Gb, err = fabrik_tree_sweep(topo, offsets, lengths, state[0], state[1], tgt, w, W, fallback)
            return (P, Gb), functools.reduce(jnp.maximum, err)
    else:
        state0 = [_batched(G0[i], B) if i in act else None for i in range(J)]

        def sweep(G):
            G, err = ccd_tree_sweep(topo, offsets, G, tgt, w, root)
            return G, functools.reduce(jnp.maximum, err)

    state, iters, errs = masked_sweeps(sweep, state0, _quat.safe_sqrt(worst0), jnp.zeros(B, jnp.int32), done0, tol,
                                       max_iters=max_iters, trace=trace, early_exit=early_exit)
    if kind == "fabrik":
        local = fabrik_tree_rotations(topo, offsets, L0, state[0], state[1])
    else:
        local = ccd_tree_rotations(topo, L0, state)
    local = [_batched(q, B) for q in local]
    P, _ = fk_tree(topo.parents, offsets, local)
    err = jnp.stack([_quat.safe_norm(_quat.sub(P[e], t)) for e, t in zip(topo.effectors, tgt)])
    return IKResult(rotations=_quat.stack([_quat.stack(q) for q in local]),
                    positions=_quat.stack([_quat.stack(_batched(p, B)) for p in P]),
                    error=err, iterations=iters, converged=jnp.all(err <= tol, axis=0), reachable=reachable,
                    trace=errs)


def check_tree_inputs(skeleton: Skeleton, targets, rotations, effectors, weights):
    """Boundary checks for tree solves; returns ``(effectors, targets, rotations, weights)`` as arrays."""
    dtype = skeleton.offsets.dtype
    effectors = check_effectors(skeleton, effectors)
    E, J = len(effectors), skeleton.num_joints
    targets = jnp.asarray(targets, dtype)
    if targets.ndim < 2 or targets.shape[-2:] != (E, 3):
        raise ValueError(f"targets must have shape (..., {E}, 3) for {E} effectors, got {targets.shape}")
    rotations = skeleton.rest_rotations() if rotations is None else jnp.asarray(rotations, dtype)
    if rotations.ndim < 2 or rotations.shape[-2:] != (J, 4):
        raise ValueError(f"rotations must have shape (..., {J}, 4) for this skeleton, got {rotations.shape}")
    if is_concrete(targets):
        check_finite("targets", targets)
    check_start_rotations(rotations)
    if weights is None:
        weights = jnp.ones((E,), dtype)
    else:
        weights = jnp.asarray(weights, dtype)
        if weights.shape != (E,):
            raise ValueError(f"weights must have shape ({E},), one per effector, got {weights.shape}")
        if is_concrete(weights):
            wv = check_finite("weights", weights)
            if np.any(wv <= 0):
                raise ValueError(f"weights must be > 0, got min {wv.min()!r}")
    return effectors, targets, _quat.unit_quaternions(rotations), weights


def solve_tree(kind, skeleton, targets, rotations, *, effectors, weights, max_iters, tol, trace, early_exit=False,
               implicit_diff=False):
    """Tree IK over any leading batch shape of ``targets (..., E, 3)``; see :func:`jaxsim.ik.solve`."""
    effectors, targets, rotations, weights = check_tree_inputs(skeleton, targets, rotations, effectors, weights)
    dtype = skeleton.offsets.dtype
    targets_in = targets
    batch = jnp.broadcast_shapes(targets.shape[:-2], rotations.shape[:-2])
    targets = jnp.broadcast_to(targets, batch + targets.shape[-2:])
    if rotations.ndim > 2:
        rotations = jnp.broadcast_to(rotations, batch + rotations.shape[-2:])
    offsets = skeleton.offsets
    if implicit_diff:
        offsets, targets, rotations = (lax.stop_gradient(a) for a in (offsets, targets, rotations))
    topo = topology(skeleton.parents, effectors)
    tgt, tol = jnp.moveaxis(targets, (-2, -1), (0, 1)), jnp.asarray(tol, dtype)
    start = bent_start(offsets, tgt, jnp.moveaxis(rotations, (-2, -1), (0, 1)), tol, topo=topo)
    res = run_tree(offsets, tgt, start, weights, tol, topo=topo, kind=kind, max_iters=int(max_iters),
                   trace=bool(trace), early_exit=bool(early_exit), bend=False)
    local = jnp.moveaxis(res.rotations, (0, 1), (-2, -1))
    P = jnp.moveaxis(res.positions, (0, 1), (-2, -1))
    err = jnp.moveaxis(res.error, 0, -1)
    reachable = jnp.moveaxis(res.reachable, 0, -1)
    if implicit_diff:
        ift = functools.partial(implicit_rotations, topo)
        for _ in batch:
            ift = jax.vmap(ift, in_axes=(0, None, 0, None, 0))
        tg = jnp.broadcast_to(targets_in, batch + targets_in.shape[-2:])
        local = ift(local, skeleton.offsets, tg, weights, jnp.all(reachable & (err <= tol), axis=-1))
        P = skeleton_fk(skeleton, local).positions
        err = jnp.sqrt(jnp.sum((P[..., list(effectors), :] - tg) ** 2, axis=-1))
    return IKResult(rotations=local, positions=P, error=err, iterations=res.iterations, converged=res.converged,
                    reachable=reachable, trace=None if res.trace is None else jnp.moveaxis(res.trace, 0, -1))
