"""The IK driver: check the inputs once, pick the kernel the topology and settings select,
lay the batch out last, and hand back an ``IKResult`` with the batch leading.

Every model is a ``Skeleton``; a chain solved for its end by FABRIK or CCD, free and
without orientation targets, takes the lean chain kernel (``kernel.run_chain``), any
other tree the tree kernel (``kernel.run_tree``), and ``LevenbergMarquardt`` its own
vmapped solve (``lm``).  Results have the same shapes on every path.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from ... import _sharding
from ..._dataclass import in_reverse_mode, is_concrete
from .._model import joints as _joints
from .._model.fk import fk
from .implicit import implicit_rotations
from .inputs import Inputs, check_flags, check_inputs, check_model
from .poles import check_poles
from .kernel import bent_start, run_chain, run_tree
from .._model.limits import limit_table
from .._solvers.lm import run_lm
from .._solvers.starts import default_start, extra_starts
from .._solvers.residual import LMProblem, _dofs
from .._model.result import IKResult
from .._solvers.settings import CCD, FABRIK, LevenbergMarquardt
from .._model.skeleton import topology
from .._model.stacked import angle_errors


def lean_chain(settings, topo, table, orientations) -> bool:
    """Whether the lean chain kernel solves this problem (a static choice)."""
    return isinstance(settings, (FABRIK, CCD)) and topo.is_chain_end and table is None and orientations is None


def _batch_last(res: IKResult, batch) -> IKResult:
    """A component-first kernel result with the batch moved to the front."""
    def lead(a):
        return None if a is None else jnp.moveaxis(a, 0, -1)

    return IKResult(rotations=jnp.moveaxis(res.rotations, (0, 1), (-2, -1)),
                    positions=jnp.moveaxis(res.positions, (0, 1), (-2, -1)),
                    error=lead(res.error), iterations=jnp.broadcast_to(res.iterations, batch),
                    converged=jnp.broadcast_to(res.converged, batch), reachable=lead(res.reachable),
                    trace=lead(res.trace), angle_error=lead(res.angle_error))


def solve_ik(settings, model, targets, *, rotations=None, effectors=None, weights=None, orientations=None,
             orientation_weights=None, sharded=None, poles=None) -> IKResult:
    """Batched IK over any leading shape of ``targets (..., E, 3)``; see :func:`jaxsim.ik.solve`."""
    check_model(model, settings)
    check_flags(("sharded",), sharded=sharded)
    trace, early_exit, implicit_diff = settings.trace, settings.early_exit, settings.implicit_diff
    unroll = getattr(settings, "unroll", None)
    if early_exit and not implicit_diff and in_reverse_mode(model, targets, rotations, orientations, weights):
        raise ValueError("early_exit=True runs the sweeps in a lax.while_loop, which JAX differentiates in forward "
                         "mode only (jax.jvp, jax.jacfwd); for jax.grad leave early_exit at None (the default: the "
                         "scan wherever the call is differentiated) or False, or set implicit_diff=True, which never "
                         "differentiates the sweeps")
    own_start = rotations is None  # LM bends the limbs of its own start, not of a caller's
    if own_start and isinstance(settings, LevenbergMarquardt):
        rotations = default_start(model)
    inp = check_inputs(model, targets, rotations, effectors, weights, orientations, orientation_weights)
    pole_limbs, pole_points = check_poles(model, poles, inp.effectors, inp.batch)
    if pole_limbs and not isinstance(settings, LevenbergMarquardt):
        raise ValueError(f"poles need solver='lm' (jaxsim.ik.LevenbergMarquardt), got {type(settings).__name__}")
    table = limit_table(model)
    topo = topology(model.parents, inp.effectors)
    lean = lean_chain(settings, topo, table, inp.orientations)
    if sharded and not lean:
        raise ValueError("sharded=True is supported for the lean chain kernel only (FABRIK or CCD on a chain solved "
                         "for its end, free, positions only); split the batch yourself")
    batch, n = inp.batch, int(np.prod(inp.batch, dtype=np.int64))
    mesh = _sharding.batch_mesh(sharded, n) if lean and batch else None
    if mesh is not None:  # split the flattened batch over the local devices
        E, J = len(inp.effectors), model.num_joints
        flat = (jnp.broadcast_to(inp.targets, batch + (E, 3)).reshape(n, E, 3),
                jnp.broadcast_to(inp.rotations, batch + (J, 4)).reshape(n, J, 4))
        (tflat, rflat), pad = _sharding.shard_leading(flat, mesh, n)
        res = solve_ik(settings, model, tflat, rotations=rflat, effectors=inp.effectors, sharded=False)
        return jax.tree_util.tree_map(lambda a: a.reshape(batch + a.shape[1:]), _sharding.unpad(res, pad))
    kw = dict(trace=bool(trace), unroll=unroll, stop=bool(implicit_diff), limbs=own_start)
    bad = None
    if not is_concrete(*(a for a in (inp.targets, inp.orientations) if a is not None)):
        bad, inp = _finite_sets(inp)  # traced: a non-finite set cannot raise here
    if early_exit is None and not implicit_diff:  # the early loop, and the scan where differentiated
        res = _early_or_scan(settings, model, inp, topo, table, lean, pole_limbs, pole_points, **kw)
    else:
        res = _run(settings, model, inp, topo, table, lean, early_exit=early_exit is not False,
                   poles=(pole_limbs, pole_points), **kw)
    if implicit_diff:
        res = _implicit(model, inp, topo, table, res, (pole_limbs, pole_points))
    return res if bad is None else _flag_nonfinite(model, inp, res, bad)


def _finite_sets(inp: Inputs):
    """``(bad (*B,), inputs)``: the sets whose targets (or orientations) hold a NaN or an inf,
    and the inputs with those replaced by finite stand-ins (so that no NaN enters a solve)."""
    bad = ~jnp.all(jnp.isfinite(inp.targets), axis=(-2, -1))
    if inp.orientations is not None:
        bad = bad | ~jnp.all(jnp.isfinite(inp.orientations), axis=(-2, -1))
    bad = jnp.broadcast_to(bad, inp.batch)
    targets = jnp.where(jnp.isfinite(inp.targets), inp.targets, 0.0)
    orients = inp.orientations
    if orients is not None:
        orients = jnp.where(jnp.all(jnp.isfinite(orients), axis=-1, keepdims=True), orients,
                            jnp.asarray([1.0, 0.0, 0.0, 0.0], orients.dtype))
    return bad, dataclasses.replace(inp, targets=targets, orientations=orients)


def _flag_nonfinite(model, inp: Inputs, res: IKResult, bad) -> IKResult:
    """``res`` with every set of non-finite targets (``bad (*B,)``, inside ``jit``) at its start
    pose, ``error`` and ``angle_error`` inf, ``iterations`` 0, not converged, not reachable:
    finite rotations and a flag no later step can mistake (as :func:`jaxsim.ik.track` does)."""
    start = jnp.broadcast_to(inp.rotations, res.rotations.shape)
    P = fk(model, start).positions
    b1, b2 = bad[..., None], bad[..., None, None]
    inf = jnp.asarray(jnp.inf, res.error.dtype)
    return IKResult(rotations=jnp.where(b2, start, res.rotations), positions=jnp.where(b2, P, res.positions),
                    error=jnp.where(b1, inf, res.error), iterations=jnp.where(bad, 0, res.iterations),
                    converged=res.converged & ~bad, reachable=res.reachable & ~b1,
                    trace=None if res.trace is None else jnp.where(b1, inf, res.trace),
                    angle_error=None if res.angle_error is None else jnp.where(b1, inf, res.angle_error),
                    stationary=None if res.stationary is None else res.stationary & ~bad)


def _early_or_scan(settings, model, inp: Inputs, topo, table, lean, pole_limbs, pole_points, **kw) -> IKResult:
    """:func:`_run` with ``early_exit``, whose derivatives (and, when differentiated, value) are
    those of the fixed-length scan: a ``custom_jvp`` whose rule is the scan's JVP.  JAX
    reverse-differentiates a ``custom_jvp`` by linearising its rule, so ``jax.grad`` works,
    also through a ``jit`` that hides the ``grad`` from :func:`in_reverse_mode`; without
    derivatives only the early loop is traced."""
    def run(early):
        def f(offsets, targets, rotations, weights, orientations, orientation_weights, points, tol):
            m = dataclasses.replace(model, offsets=offsets)
            i = dataclasses.replace(inp, targets=targets, rotations=rotations, weights=weights,
                                    orientations=orientations, orientation_weights=orientation_weights)
            return _run(settings, m, i, topo, table, lean, early_exit=early, poles=(pole_limbs, points), tol=tol, **kw)
        return f

    tol = jnp.asarray(settings.tol, model.offsets.dtype)
    args = (model.offsets, inp.targets, inp.rotations, inp.weights, inp.orientations, inp.orientation_weights,
            pole_points, tol)
    early = jax.custom_jvp(run(True))
    early.defjvp(lambda primals, tangents: jax.jvp(run(False), primals, tangents))
    return early(*args)


def _run(settings, model, inp: Inputs, topo, table, lean, *, trace, unroll, early_exit, stop, limbs=False,
         poles=((), None), tol=None) -> IKResult:
    """The selected kernel on the checked inputs (``stop``: no derivatives through it; ``limbs``:
    LM's given start gets the limb start, ``lm.run_lm``; ``poles``: ``(limbs, points (*B, K, 3))``
    from ``poles.check_poles``, LM only)."""
    batch, dtype, J = inp.batch, model.offsets.dtype, model.num_joints
    n = int(np.prod(batch, dtype=np.int64))
    offsets, targets, rotations = model.offsets, inp.targets, inp.rotations
    if stop:  # the sweeps are not differentiated; see _implicit
        offsets, targets, rotations = (lax.stop_gradient(a) for a in (offsets, targets, rotations))
    targets = jnp.broadcast_to(targets, batch + targets.shape[-2:])
    if rotations.ndim > 2:  # else one start pose for the whole batch
        rotations = jnp.broadcast_to(rotations, batch + rotations.shape[-2:])
    tol = jnp.asarray(settings.tol if tol is None else tol, dtype)
    kw = dict(max_iters=int(settings.max_iters), trace=trace, early_exit=early_exit)
    if lean:
        res = run_chain(offsets, jnp.moveaxis(targets[..., 0, :], -1, 0), jnp.moveaxis(rotations, (-2, -1), (0, 1)),
                        tol, alg=type(settings), unroll=_joints.unrolled(J, unroll, n), **kw)
        return _batch_last(res, batch)
    orients = inp.orientations
    if orients is not None:
        orients = jnp.broadcast_to(orients, batch + orients.shape[-2:])
    start = bent_start(offsets, targets, rotations, tol, topo=topo)  # (*B, J, 4)
    if isinstance(settings, LevenbergMarquardt):  # LM too starts bent: on its target's line J^T r = 0
        rot = start.reshape((n, J, 4))
        extra = extra_starts(model, settings.seeds) if settings.seeds > 1 else None  # the same for every set

        def flat(a):
            return None if a is None else a.reshape((n,) + a.shape[-2:])

        pole_limbs, pole_points = poles
        if pole_points is not None:
            pole_points = pole_points.reshape((n,) + pole_points.shape[-2:])
            if stop:
                pole_points = lax.stop_gradient(pole_points)
        res = run_lm(offsets, flat(targets), rot, inp.weights, tol, table, flat(orients), inp.orientation_weights,
                     jnp.asarray(settings.damping, dtype), extra, topo=topo, limbs=limbs, poles=pole_points,
                     pole_limbs=pole_limbs, **kw)
        return jax.tree_util.tree_map(lambda x: x.reshape(batch + x.shape[1:]), res)
    res = run_tree(offsets, jnp.moveaxis(targets, (-2, -1), (0, 1)), jnp.moveaxis(start, (-2, -1), (0, 1)),
                   inp.weights, tol, table,
                   None if orients is None else jnp.moveaxis(orients, (-2, -1), (0, 1)), inp.orientation_weights,
                   topo=topo, alg=type(settings), **kw)
    return _batch_last(res, batch)


def _implicit(model, inp: Inputs, topo, table, res: IKResult, poles=((), None)) -> IKResult:
    """The solution with implicit-function derivatives (``implicit``; active limits held),
    its FK and errors."""
    orient = inp.orientations is not None
    dofs = _dofs(topo, table, orient)
    batch = inp.batch
    tg = jnp.broadcast_to(inp.targets, batch + inp.targets.shape[-2:])
    met = res.converged & jnp.all(res.reachable, axis=-1)  # every target (orientation, pole) within tol
    orients = None if not orient else jnp.broadcast_to(inp.orientations, batch + inp.orientations.shape[-2:])

    pole_limbs, pole_points = poles

    def one(q, targets, ors, pl, gn):
        prob = LMProblem(targets, inp.weights, ors, inp.orientation_weights, pl, pole_limbs)
        return implicit_rotations(topo, dofs, q, model.offsets, prob, table, gn)

    ift = one
    for _ in batch:
        ift = jax.vmap(ift, in_axes=(0, 0, None if orients is None else 0, None if pole_points is None else 0, 0))
    local = ift(res.rotations, tg, orients, pole_points, met)
    pose = fk(model, local)
    P = pose.positions
    err = jnp.sqrt(jnp.sum((P[..., list(inp.effectors), :] - tg) ** 2, axis=-1))
    ang = None if orients is None else angle_errors(pose.rotations, inp.effectors, orients)
    return IKResult(rotations=local, positions=P, error=err, iterations=res.iterations, converged=res.converged,
                    reachable=res.reachable, trace=res.trace, angle_error=ang, stationary=res.stationary)
