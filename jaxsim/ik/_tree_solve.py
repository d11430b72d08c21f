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
from ._tree_pose import batched as _batched, bone_lengths, finish, reachable_flags
from ._limits import limit_table, project_all
from ._lm import run_lm
from ._tree_sweeps import (branch_weights, ccd_tree_rotations, ccd_tree_sweep, effector_sq_errors,
                           fabrik_tree_rotations, fabrik_tree_sweep, fabrik_tree_sweep_frames)


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
def run_tree(offsets, targets, local0, weights, tol, table=None, orients=None, orient_weights=None, *, topo, kind,
             max_iters, trace, early_exit=False, bend=True):
    """Tree IK on component-first arrays.

    Args:
      offsets: ``(J, 3)``; targets: ``(E, 3, *B)``; local0: ``(J, 4, *B)`` or ``(J, 4)``
      (one start pose for the batch); weights: ``(E,)``; tol: scalar.
      table: ``LimitTable`` or ``None`` (all joints free).  The start pose is projected
        onto the limits, and so is every sweep's.
      orients: ``(E, 4, *B)`` target orientations of the effectors, or ``None``;
        orient_weights: ``(E,)`` scene units per radian.
      bend: bend straight branches first (see :func:`bent_start`); False when the
        caller has done so.

    Returns:
      ``IKResult`` in the component-first layout: ``rotations (J, 4, *B)``,
      ``positions (J, 3, *B)``, ``error (E, *B)``, ``reachable (E, *B)``, ``(*B)``
      iterations and converged, ``trace (max_iters, *B)`` (the worst effector) or
      ``None``, ``angle_error (E, *B)`` or ``None``.
    """
    J, E = len(topo.parents), len(topo.effectors)
    B = targets.shape[2:]
    dtype = offsets.dtype
    tgt = [_quat.unstack(targets[k]) for k in range(E)]
    w = [weights[k] for k in range(E)]
    orient = None if orients is None else ([_quat.unstack(orients[k]) for k in range(E)],
                                           [orient_weights[k] for k in range(E)])
    root = _batched(_quat.unstack(offsets[0]), B)
    lengths = bone_lengths(offsets)
    reachable = reachable_flags(topo, offsets, tgt, B)
    L0 = [_quat.renormalize(_quat.unstack(local0[i])) for i in range(J)]
    P0, G0 = fk_tree(topo.parents, offsets, L0)
    if bend:  # FABRIK paper §5.4, per branch
        L0 = break_symmetry_tree(topo, offsets, L0, P0, G0, tgt, tol)
        P0, G0 = fk_tree(topo.parents, offsets, L0)
    if table is not None:
        L0 = project_all(table, L0)
        P0, G0 = fk_tree(topo.parents, offsets, L0)
    worst0 = functools.reduce(jnp.maximum, effector_sq_errors(topo, P0, G0, tgt, orient))
    done0 = jnp.broadcast_to(worst0 <= tol * tol, B)
    act = set(topo.active)
    framed = table is not None or orient is not None
    if kind == "fabrik":
        W = branch_weights(topo, w)
        fallback = (jnp.zeros((), dtype), jnp.zeros((), dtype), jnp.ones((), dtype))
        subbase = [len(c) > 1 for c in topo.active_children]
        second = [_batched(L0[i] if framed else G0[i], B) if (framed or subbase[i]) and i in act else None
                  for i in range(J)]
        state0 = ([_batched(P0[i], B) if i in act else None for i in range(J)], second)

        def sweep(state):
            if framed:
                P, R, err = fabrik_tree_sweep_frames(topo, offsets, lengths, state[0], state[1], tgt, w, W, fallback,
                                                     table, orient)
            else:
                P, R, err = fabrik_tree_sweep(topo, offsets, lengths, state[0], state[1], tgt, w, W, fallback)
            return (P, R), functools.reduce(jnp.maximum, err)
    else:
        state0 = [_batched(G0[i], B) if i in act else None for i in range(J)]

        def sweep(G):
            G, err = ccd_tree_sweep(topo, offsets, G, tgt, w, root, table, orient)
            return G, functools.reduce(jnp.maximum, err)

    state, iters, errs = masked_sweeps(sweep, state0, _quat.safe_sqrt(worst0), jnp.zeros(B, jnp.int32), done0, tol,
                                       max_iters=max_iters, trace=trace, early_exit=early_exit, keep_best=framed)
    if kind == "fabrik" and framed:
        local = [state[1][i] if i in act else L0[i] for i in range(J)]
    elif kind == "fabrik":
        local = fabrik_tree_rotations(topo, offsets, L0, state[0], state[1])
    else:
        local = ccd_tree_rotations(topo, L0, state, table, orient is not None)
    local = [_batched(q, B) for q in local]
    return finish(topo, offsets, local, tgt, orient, tol, iters, reachable, errs)


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


#: Default orientation weight (scene units per radian): 1 degree of error weighs as ~1.7 mm.
ORIENTATION_WEIGHT = 0.1


def check_orientations(skeleton, orientations, orientation_weights, E):
    """``(orientations (..., E, 4), weights (E,))`` as arrays, or ``(None, None)``.

    Raises ``ValueError`` on a wrong shape, non-finite values, a quaternion whose norm is
    not 1 (to 1e-4), or negative weights.
    """
    dtype = skeleton.offsets.dtype
    if orientations is None:
        if orientation_weights is not None:
            raise ValueError("orientation_weights needs orientations")
        return None, None
    o = jnp.asarray(orientations, dtype)
    if o.ndim < 2 or o.shape[-2:] != (E, 4):
        raise ValueError(f"orientations must have shape (..., {E}, 4), one unit quaternion per effector, got {o.shape}")
    if is_concrete(o):
        ov = check_finite("orientations", o).astype(np.float64)
        norms = np.linalg.norm(ov, axis=-1)
        if np.any(np.abs(norms - 1.0) > 1e-4):
            raise ValueError(f"orientations must be unit quaternions; {int(np.sum(np.abs(norms - 1.0) > 1e-4))} "
                             f"have a norm off 1 by more than 1e-4 (worst {norms.flat[np.argmax(np.abs(norms - 1))]!r})")
    o = _quat.unit_quaternions(o)
    if orientation_weights is None:
        ow = jnp.full((E,), ORIENTATION_WEIGHT, dtype)
    else:
        ow = jnp.asarray(orientation_weights, dtype)
        if ow.shape != (E,):
            raise ValueError(f"orientation_weights must have shape ({E},), got {ow.shape}")
        if is_concrete(ow) and np.any(check_finite("orientation_weights", ow) < 0):
            raise ValueError("orientation_weights must be >= 0")
    return o, ow


def solve_tree(settings, skeleton, targets, rotations, *, effectors, weights, trace, early_exit=False,
               implicit_diff=False, orientations=None, orientation_weights=None):
    """Tree IK over any leading batch shape of ``targets (..., E, 3)``; see :func:`jaxsim.ik.solve`."""
    kind, max_iters, tol = settings.kind, settings.max_iters, settings.tol
    effectors, targets, rotations, weights = check_tree_inputs(skeleton, targets, rotations, effectors, weights)
    orients, ow = check_orientations(skeleton, orientations, orientation_weights, len(effectors))
    table = limit_table(skeleton)
    if implicit_diff and (table is not None or orients is not None):
        raise ValueError("implicit_diff=True needs a free skeleton without orientation targets (the implicit "
                         "derivative ignores active limits); differentiate through the sweeps instead")
    dtype = skeleton.offsets.dtype
    targets_in = targets
    batch = jnp.broadcast_shapes(targets.shape[:-2], rotations.shape[:-2],
                                 () if orients is None else orients.shape[:-2])
    targets = jnp.broadcast_to(targets, batch + targets.shape[-2:])
    if orients is not None:
        orients = jnp.broadcast_to(orients, batch + orients.shape[-2:])
    if rotations.ndim > 2:
        rotations = jnp.broadcast_to(rotations, batch + rotations.shape[-2:])
    offsets = skeleton.offsets
    if implicit_diff:
        offsets, targets, rotations = (lax.stop_gradient(a) for a in (offsets, targets, rotations))
    topo = topology(skeleton.parents, effectors)
    tol = jnp.asarray(tol, dtype)
    tgt = jnp.moveaxis(targets, (-2, -1), (0, 1))
    start = bent_start(offsets, tgt, jnp.moveaxis(rotations, (-2, -1), (0, 1)), tol, topo=topo)
    if kind == "lm":  # LM too starts bent: on its target's line a straight branch has J^T r = 0
        n = int(np.prod(batch, dtype=np.int64))
        rot = jnp.moveaxis(start, (0, 1), (-2, -1)).reshape((n,) + rotations.shape[-2:])
        res = run_lm(offsets, targets.reshape((n,) + targets.shape[-2:]), rot, weights, tol, table,
                     None if orients is None else orients.reshape((n,) + orients.shape[-2:]), ow,
                     jnp.asarray(settings.damping, dtype), topo=topo, max_iters=int(max_iters), trace=bool(trace),
                     early_exit=bool(early_exit))
        return jax.tree_util.tree_map(lambda x: x.reshape(batch + x.shape[1:]), res)
    res = run_tree(offsets, tgt, start, weights, tol, table,
                   None if orients is None else jnp.moveaxis(orients, (-2, -1), (0, 1)), ow, topo=topo, kind=kind,
                   max_iters=int(max_iters), trace=bool(trace), early_exit=bool(early_exit), bend=False)
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
                    reachable=reachable, trace=None if res.trace is None else jnp.moveaxis(res.trace, 0, -1),
                    angle_error=None if res.angle_error is None else jnp.moveaxis(res.angle_error, 0, -1))
