"""CCD and FABRIK as fixed-length ``lax.scan`` loops with masked no-ops after convergence.

Both solvers share one driver: validate at the boundary, move the quaternion/vector
component axis to the front (``(J, 4, *B)``, ``(3, *B)``) so any batch trails and every
joint update is one elementwise fusion over the batch, then scan ``max_iters`` sweeps.
Once an element is within ``tol`` its state is frozen by ``where`` and its iteration
counter stops, so ``vmap`` and reverse-mode ``grad`` work on the whole fixed-length loop
(the JAXopt pattern).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._dataclass import is_concrete
from .._validate import check_finite
from . import _joints, _quat
from ._ccd import ccd_sweep
from ._chain import Chain
from ._fabrik import fabrik_sweep, rotations_from_positions, straight_towards
from ._fk import expand, fk_component_first
from ._result import IKResult

SOLVERS = ("ccd", "fabrik")

#: Bend applied to a chain lying on the line of its target (FABRIK paper, section 5.4).
SYMMETRY_BREAK_ANGLE = 0.1


def _norm(v):
    return _quat.safe_norm(v)


def break_symmetry(offsets, local, positions, target, reach, done, *, unroll: bool):
    """Bend a chain that lies on the line through its root and target.

    Neither CCD nor FABRIK can leave that line by itself (every update is a rotation
    about a zero axis, or a move along the line).  Such poses get joint 1 (or the root of
    a one-bone chain) turned by ``SYMMETRY_BREAK_ANGLE`` about an axis perpendicular to
    the line; other poses are returned unchanged.

    Args:
      local: ``(J, 4, *B)``; positions: ``(J, 3, *B)`` = FK of ``local``;
      target: ``(3, *B)``; reach: ``(*B)`` or scalar; done: ``(*B)`` bool.
    """
    J = local.shape[0]
    root = positions[0]
    chain_dir = _quat.normalize(positions[J - 1] - root, _quat.perpendicular(target - root))
    ray = _quat.normalize(target - root, chain_dir)
    rel = jnp.swapaxes(positions - root, 0, 1)  # (3, J, *B)
    off_line = jnp.max(_norm(_quat.cross(rel, ray[:, None])), axis=0)
    need = (off_line <= 1e-6 * reach) & ~done
    m = 1 if J > 2 else 0
    half = float(0.5 * SYMMETRY_BREAK_ANGLE)
    r = jnp.concatenate([jnp.full_like(ray[:1], np.cos(half)), float(np.sin(half)) * _quat.perpendicular(ray)])
    if m > 0:
        _, G = fk_component_first(offsets, local, unroll=unroll)
        g_parent = G[m - 1]
    else:
        g_parent = _quat.identity(ray.shape[1:], local.dtype)
    lm = _quat.mul(_quat.conj(g_parent), _quat.mul(r, _quat.mul(g_parent, local[m])))
    return jnp.where(need, local.at[m].set(lm), local)


def _where_tree(c, a, b):
    return jax.tree_util.tree_map(lambda x, y: jnp.where(c, x, y), a, b)


@functools.partial(jax.jit, static_argnames=("kind", "max_iters", "unroll", "trace"))
def _run(offsets, target, local0, tol, *, kind, max_iters, unroll, trace):
    """The solver on component-first arrays: ``target (3, *B)``, ``local0 (J, 4, *B)``."""
    J = local0.shape[0]
    nb = target.ndim - 1
    root = expand(offsets[0], nb).astype(target.dtype)
    lengths = expand(jnp.sqrt(jnp.sum(offsets[1:] ** 2, axis=-1)), nb + 1).astype(target.dtype)
    reach = jnp.sum(lengths, axis=0)[0]
    local0 = _quat.renormalize(local0, axis=1)

    P0, _ = fk_component_first(offsets, local0, unroll=unroll)
    err0 = _norm(P0[J - 1] - target)
    done0 = err0 <= tol
    reachable = _norm(target - root) <= reach
    local0 = break_symmetry(offsets, local0, P0, target, reach, done0, unroll=unroll)
    P0, G0 = fk_component_first(offsets, local0, unroll=unroll)

    if kind == "ccd":
        state0 = (local0, P0, G0)

        def sweep(state):
            return ccd_sweep(offsets, target, *state, unroll=unroll)

        def end_of(state):
            return state[1][J - 1]

        stop_early = jnp.zeros_like(done0)
    else:
        fallback = _quat.perpendicular(target - root)
        straight = straight_towards(root, target, lengths, J, fallback)
        straight = _joints.split(_joints.stack(straight), unroll)
        state0 = _joints.split(P0, unroll)

        def sweep(state):
            new = fabrik_sweep(state, target, root, lengths, unroll=unroll)
            return _where_tree(reachable, new, straight)

        def end_of(state):
            return _joints.get(state, J - 1)

        stop_early = ~reachable  # the straight line is final

    def body(carry, _):
        state, err, iters, done = carry
        new = sweep(state)
        new_err = _norm(end_of(new) - target)
        state = _where_tree(done, state, new)
        err = jnp.where(done, err, new_err)
        iters = iters + (~done).astype(jnp.int32)
        done = done | (err <= tol) | stop_early
        return (state, err, iters, done), (err if trace else None)

    iters0 = jnp.zeros(done0.shape, jnp.int32)
    (state, _, iters, _), errs = lax.scan(body, (state0, err0, iters0, done0), None, length=max_iters)

    if kind == "ccd":
        local, P, _ = state
    else:
        local = rotations_from_positions(offsets, local0, _joints.stack(state), unroll=unroll)
        P, _ = fk_component_first(offsets, local, unroll=unroll)
    err = _norm(P[J - 1] - target)
    return local, P, err, iters, err <= tol, reachable, errs


def _check_target_and_rotations(chain, target, rotations):
    J = chain.num_joints
    if target.shape[-1:] != (3,):
        raise ValueError(f"target must have shape (..., 3), got {target.shape}")
    if rotations.shape[-2:] != (J, 4):
        raise ValueError(f"rotations must have shape (..., {J}, 4) for this chain, got {rotations.shape}")
    if is_concrete(target):
        check_finite("target", target)
    if is_concrete(rotations):
        r = check_finite("rotations", rotations)
        if np.any(np.linalg.norm(r, axis=-1) < 1e-6):
            raise ValueError("rotations contain a zero quaternion; use (1, 0, 0, 0) for no rotation")


def _solve(kind, chain, target, rotations, *, max_iters, tol, trace, unroll):
    if kind not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {kind!r}")
    if not isinstance(chain, Chain):
        raise TypeError(f"chain must be a jaxsim.ik.Chain, got {type(chain).__name__}")
    if not (isinstance(max_iters, (int, np.integer)) and max_iters >= 1):
        raise ValueError(f"max_iters must be an int >= 1, got {max_iters!r}")
    if is_concrete(tol) and not (np.ndim(tol) == 0 and float(tol) >= 0 and np.isfinite(tol)):
        raise ValueError(f"tol must be a finite scalar >= 0, got {tol!r}")
    dtype = chain.offsets.dtype
    target = jnp.asarray(target, dtype)
    rotations = chain.rest_rotations() if rotations is None else jnp.asarray(rotations, dtype)
    _check_target_and_rotations(chain, target, rotations)
    batch = jnp.broadcast_shapes(target.shape[:-1], rotations.shape[:-2])
    target = jnp.broadcast_to(target, batch + (3,))
    rotations = jnp.broadcast_to(rotations, batch + rotations.shape[-2:])
    J = chain.num_joints
    local, P, err, iters, conv, reachable, errs = _run(
        chain.offsets,
        jnp.moveaxis(target, -1, 0),
        jnp.moveaxis(rotations, (-2, -1), (0, 1)),
        jnp.asarray(tol, dtype),
        kind=kind,
        max_iters=int(max_iters),
        unroll=_joints.unrolled(J, unroll),
        trace=bool(trace),
    )
    return IKResult(
        rotations=jnp.moveaxis(local, (0, 1), (-2, -1)),
        positions=jnp.moveaxis(P, (0, 1), (-2, -1)),
        error=err,
        iterations=iters,
        converged=conv,
        reachable=reachable,
        trace=None if errs is None else jnp.moveaxis(errs, 0, -1),
    )


def ccd(chain: Chain, target, rotations=None, *, max_iters: int = 100, tol=1e-4,
        trace: bool = True, unroll: bool | None = None) -> IKResult:
    """Cyclic coordinate descent IK.

    Args:
      chain: the chain, ``offsets (J, 3)``.
      target: ``(3,)`` world target, or ``(..., 3)`` for a batch.
      rotations: ``(J, 4)`` (or ``(..., J, 4)``) local start rotations; ``None`` = rest pose.
      max_iters: number of sweeps scanned (static; a new value recompiles).
      tol: stop when ``|end - target| <= tol`` (scene units).
      trace: also return the per-sweep error ``trace (..., max_iters)``.
      unroll: unroll the loop over joints (default: ``J <= 16``).

    Returns:
      ``IKResult``.  Sweeps after convergence are masked no-ops.
    """
    return _solve("ccd", chain, target, rotations, max_iters=max_iters, tol=tol, trace=trace, unroll=unroll)


def fabrik(chain: Chain, target, rotations=None, *, max_iters: int = 100, tol=1e-4,
           trace: bool = True, unroll: bool | None = None) -> IKResult:
    """FABRIK IK (Aristidou & Lasenby 2011), with rotations rebuilt from the positions.

    Arguments and result as for :func:`ccd`.  An unreachable target gets the straight
    chain towards it after one sweep, with ``converged=False``.
    """
    return _solve("fabrik", chain, target, rotations, max_iters=max_iters, tol=tol, trace=trace, unroll=unroll)


def solve(chain: Chain, targets, *, solver: str = "fabrik", rotations=None, max_iters: int = 100,
          tol=1e-4, trace: bool = False, unroll: bool | None = None) -> IKResult:
    """Batched IK over any leading shape of ``targets (..., 3)``.

    ``rotations`` may be ``(J, 4)`` (shared start pose) or ``(..., J, 4)``.  The batch
    trails in memory inside the kernel, so a large batch is one elementwise loop per
    joint update.  Per-sweep traces are off by default to save memory.
    """
    return _solve(solver, chain, targets, rotations, max_iters=max_iters, tol=tol, trace=trace, unroll=unroll)
