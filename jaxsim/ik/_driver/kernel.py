"""The compiled sweep kernels: one for any tree, and the lean one its chains select.

Both lay the batch out last (component-first arrays: ``(J, 4, *B)``, ``(E, 3, *B)``), so
any batch trails and every joint update is one elementwise fusion over the batch; both
run the algorithm's :class:`_loop.SweepPlan`, looked up by the settings type
(``PLANS``), in the masked sweep loop.  :func:`run_chain` is the static specialisation
for a chain solved for its end (``Topology.is_chain_end``), free and without
orientation targets: per-joint lists for batches, or a rolled ``fori_loop`` over
stacked joints for long chains and single targets (``joints``).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp

from ..._geometry import quat as _quat
from .._solvers import ccd as _ccd
from .._solvers import fabrik as _fabrik
from .._model import joints as _joints
from .._model.fk import fk_joints
from .._model.stacked import _s, fk_stacked, joint_rows, project_stacked
from .._model.limits import LimitTable
from .._solvers.loop import run_plan
from .._model.pose import OrientTargets, batched, bone_lengths, effector_sq_errors, finish, reachable_flags
from .._model.result import IKResult
from .._solvers.settings import CCD, FABRIK
from .._solvers.symmetry import bend_straight, break_symmetry_chain, break_symmetry_stacked

#: Per settings type, the module that lays out its sweeps (``chain_plan``, ``tree_plan``).
PLANS = {FABRIK: _fabrik, CCD: _ccd}


@dataclasses.dataclass(frozen=True)
class ChainStart:
    """A chain's start, as the chain plans read it (inside a trace).

    Attributes:
      offsets: ``(J, 3)``; target, root: vector tuples over ``batch``.
      lengths: ``(J-1,)`` bone lengths; reachable: ``B`` bools.
      local, positions, frames: the start pose's containers (``joints``), bent when
        it lay on its target's line.
      err, done: ``B``-shaped start error and within-``tol`` flags.
      batch: ``B``; unroll: per-joint lists (True) or stacked arrays.
    """

    offsets: jax.Array
    target: tuple
    root: tuple
    lengths: jax.Array
    reachable: jax.Array
    local: Any
    positions: Any
    frames: Any
    err: jax.Array
    done: jax.Array
    batch: tuple
    unroll: bool


@dataclasses.dataclass(frozen=True)
class TreeStart:
    """A tree's start, as the tree plans read it (inside a trace).

    Attributes:
      topo: ``Topology``; offsets: ``(J, 3)``; lengths: ``(J,)`` (``lengths[0] = 0``).
      targets: ``E`` vector tuples; weights: ``E`` scalars.
      orient: ``OrientTargets`` or ``None``; table: ``LimitTable`` or ``None``.
      local, positions, frames: lists of ``J`` tuples, the start pose (projected onto
        the limits) and its FK.
      err, done: ``B``-shaped start error (the worst effector) and within-``tol`` flags.
      batch: ``B``.
    """

    topo: Any
    offsets: jax.Array
    lengths: jax.Array
    targets: list
    weights: list
    orient: OrientTargets | None
    table: LimitTable | None
    local: list
    positions: list
    frames: list
    err: jax.Array
    done: jax.Array
    batch: tuple


@functools.partial(jax.jit, static_argnames=("alg", "max_iters", "unroll", "trace", "early_exit"))
def run_chain(offsets, target, local0, tol, *, alg, max_iters, unroll, trace, early_exit=False):
    """The lean chain kernel: ``target (3, *B)``, ``local0 (J, 4, *B)`` or ``(J, 4)`` (one
    start pose for the whole batch); ``alg`` is the settings type.  A start pose on the
    line of its target is bent first (FABRIK paper §5.4, ``symmetry``).

    Returns the component-first ``IKResult``: ``rotations (J, 4, *B)``, ``positions
    (J, 3, *B)``, ``error`` and ``reachable (1, *B)``, ``(*B)`` iterations and
    converged, ``trace (max_iters, *B)`` or ``None``.
    """
    J, B, dtype = local0.shape[0], target.shape[1:], local0.dtype
    tgt = _quat.unstack(target)
    root = batched(_quat.unstack(offsets[0]), B)
    lengths = jnp.sqrt(jnp.sum(offsets[1:] ** 2, axis=-1))
    reach = jnp.sum(lengths)
    reachable = _quat.safe_norm(_quat.sub(tgt, root)) <= reach
    if unroll:  # a shared start pose goes through FK once, without the batch axes
        L0 = [_quat.renormalize(_quat.unstack(local0[i])) for i in range(J)]
        P0, G0 = fk_joints(offsets, L0, local0.shape[2:], unroll=True)
        err0 = _quat.safe_norm(_quat.sub(P0[J - 1], tgt))  # an element it bends is not done: its error
        done0 = err0 <= tol  # is overwritten by its first sweep
        L0, P0, G0 = break_symmetry_chain(L0, P0, G0, tgt, reach, done0)
    else:
        local0 = jnp.broadcast_to(local0.reshape(local0.shape + (1,) * (len(B) + 2 - local0.ndim)), (J, 4) + B)
        L0 = _quat.stack(_quat.renormalize(_quat.unstack(local0, axis=1)), axis=1)
        P0, G0 = fk_joints(offsets, L0, B, unroll=False)
        err0 = _quat.safe_norm(_quat.sub(_quat.unstack(P0[J - 1]), tgt))
        done0 = err0 <= tol
        L0 = break_symmetry_stacked(L0, P0, G0, tgt, reach, done0, B)
        P0, G0 = fk_joints(offsets, L0, B, unroll=False)
    start = ChainStart(offsets=offsets, target=tgt, root=root, lengths=lengths, reachable=reachable, local=L0,
                       positions=P0, frames=G0, err=jnp.broadcast_to(err0, B), done=jnp.broadcast_to(done0, B),
                       batch=B, unroll=unroll)
    local, iters, errs = run_plan(PLANS[alg].chain_plan(start), tol, max_iters=max_iters, trace=trace,
                                  early_exit=early_exit)
    P, _ = fk_joints(offsets, local, B, unroll=unroll)
    err = _quat.safe_norm(_quat.sub(_joints.get(P, J - 1), tgt))
    return IKResult(rotations=_joints.stack(local).astype(dtype), positions=_joints.stack(P), error=err[None],
                    iterations=iters, converged=err <= tol, reachable=reachable[None], trace=errs)


@functools.partial(jax.jit, static_argnames=("topo",))
def bent_start(offsets, targets, local0, tol, *, topo):
    """``(*B, J, 4)`` start rotations with straight branches on their targets' lines bent
    (``symmetry.bend_straight``): ``targets (*B, E, 3)``, ``local0 (*B, J, 4)`` or ``(J, 4)``
    (one start for the batch), batch-leading.  Its own program when called eagerly: inside
    the sweeps' it would be compiled again with each of them."""
    L0 = _s(_quat.renormalize(_quat.unstack(local0, axis=-1)))
    P0, G0 = fk_stacked(topo.parents, offsets, L0)
    return bend_straight(topo, L0, P0, G0, targets, tol)


def orient_targets(orients, orient_weights):
    """``OrientTargets`` of ``orients (E, 4, *B)`` and ``orient_weights (E,)``, or ``None``."""
    if orients is None:
        return None
    E = orients.shape[0]
    return OrientTargets([_quat.unstack(orients[k]) for k in range(E)], [orient_weights[k] for k in range(E)])


@functools.partial(jax.jit, static_argnames=("topo", "alg", "max_iters", "trace", "early_exit"))
def run_tree(offsets, targets, local0, weights, tol, table=None, orients=None, orient_weights=None, *, topo, alg,
             max_iters, trace, early_exit=False):
    """The tree kernel on component-first arrays.

    Args:
      offsets: ``(J, 3)``; targets: ``(E, 3, *B)``; local0: ``(J, 4, *B)`` or ``(J, 4)``
        (one start pose for the batch), already bent (:func:`bent_start`); weights:
        ``(E,)``; tol: scalar.
      table: ``LimitTable`` or ``None`` (all joints free).  The start pose is projected
        onto the limits, and so is every sweep's.
      orients: ``(E, 4, *B)`` target orientations of the effectors, or ``None``;
        orient_weights: ``(E,)`` scene units per radian.
      topo: static ``Topology``; alg: the settings type.

    Returns:
      ``IKResult`` in the component-first layout: ``rotations (J, 4, *B)``,
      ``positions (J, 3, *B)``, ``error (E, *B)``, ``reachable (E, *B)``, ``(*B)``
      iterations and converged, ``trace (max_iters, *B)`` (the worst effector) or
      ``None``, ``angle_error (E, *B)`` or ``None``.
    """
    E, B = len(topo.effectors), targets.shape[2:]
    tgt = [_quat.unstack(targets[k]) for k in range(E)]
    orient = orient_targets(orients, orient_weights)
    # the start on stacked joints (``stacked``: FK by tree level, the projection over all
    # joints at once): a fraction of the per-joint code to compile
    L0 = project_stacked(table, _s(_quat.renormalize(_quat.unstack(jnp.moveaxis(local0, (0, 1), (-2, -1)), axis=-1))))
    P0, G0 = (joint_rows(x) for x in fk_stacked(topo.parents, offsets, L0))
    L0 = joint_rows(L0)
    worst0 = functools.reduce(jnp.maximum, effector_sq_errors(topo, P0, G0, tgt, orient))
    start = TreeStart(topo=topo, offsets=offsets, lengths=bone_lengths(offsets), targets=tgt,
                      weights=[weights[k] for k in range(E)], orient=orient, table=table, local=L0, positions=P0,
                      frames=G0, err=jnp.broadcast_to(_quat.safe_sqrt(worst0), B),
                      done=jnp.broadcast_to(worst0 <= tol * tol, B), batch=B)
    local, iters, errs = run_plan(PLANS[alg].tree_plan(start), tol, max_iters=max_iters, trace=trace,
                                  early_exit=early_exit)
    return finish(topo, offsets, local, tgt, orient, tol, iters, reachable_flags(topo, offsets, tgt, B), errs)
