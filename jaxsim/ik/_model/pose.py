"""A pose as solver data: bone lengths, reachability, effector errors, and the ``IKResult``
of local rotations.  Shared by the sweep solvers and LM on any tree (a chain is one)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from ..._geometry import quat as _quat
from .stacked import angle_errors, fk_stacked, take
from .projection import project
from .result import IKResult


@dataclasses.dataclass(frozen=True)
class OrientTargets:
    """Effector orientation targets, per effector slot (inside a solve).

    Attributes:
      rotations: list of ``E`` unit quaternion tuples, the target world orientations.
      weights: list of ``E`` scalars, scene units per radian.
    """

    rotations: list
    weights: list


def batched(v, B):
    """A component tuple broadcast to batch shape ``B`` (``None`` stays ``None``)."""
    return None if v is None else tuple(jnp.broadcast_to(c, B) for c in v)


def bone_lengths(offsets):
    """``(J,)`` bone lengths, ``lengths[0] = 0`` (no ``sqrt(0)``)."""
    return jnp.concatenate([jnp.zeros((1,), offsets.dtype), jnp.sqrt(jnp.sum(offsets[1:] ** 2, axis=-1))])


def reachable_flags(topo, offsets, tgt, B):
    """``(E, *B)``: each target within the summed bone lengths of its effector's path from the root."""
    lengths = bone_lengths(offsets)
    root = batched(_quat.unstack(offsets[0]), B)
    reach = [sum(lengths[j] for j in path[1:]) if len(path) > 1 else jnp.zeros((), offsets.dtype)
             for path in topo.path]
    return jnp.stack([_quat.safe_norm(_quat.sub(t, root)) <= r for t, r in zip(tgt, reach)])


def local_of(gp, g):
    """The local rotation ``G_p^{-1} G`` (renormalised) of frame ``g`` under parent frame ``gp`` (``None``: the root)."""
    return _quat.renormalize(g if gp is None else _quat.mul(_quat.conj(gp), g))


def limited(table, i, q):
    """Joint ``i``'s rotation ``q`` projected onto its limit set (``table`` ``None``: all free)."""
    return q if table is None or table.kinds[i] == "free" else project(q, table.joint(i))


def moving_joints(topo, orient: bool) -> tuple:
    """Joints a solver may turn: an effector strictly below, or (with orientation targets) an effector."""
    return topo.moving if not orient else tuple(sorted(set(topo.moving) | set(topo.effectors)))


def effector_sq_errors(topo, P, G, targets, orient: OrientTargets | None):
    """Per effector, ``max(|p - t|, weight * angle)^2`` (just ``|p - t|^2`` without orientations)."""
    err = [_quat.sqnorm(_quat.sub(P[e], t)) for e, t in zip(topo.effectors, targets)]
    if orient is None:
        return err
    return [jnp.maximum(e2, (orient.weights[k] * _quat.angle(_quat.mul(_quat.conj(orient.rotations[k]), G[e]))) ** 2)
            for k, (e, e2) in enumerate(zip(topo.effectors, err))]


def finish(topo, offsets, L, tgt, orient: OrientTargets | None, tol, iters, reachable, errs):
    """The component-first ``IKResult`` of the local rotations ``L (*B, J, 4)``; FK and the
    errors on stacked joints (``stacked``)."""
    B = jnp.shape(iters)
    P, G = fk_stacked(topo.parents, offsets, L)
    eff = topo.effectors
    t = jnp.stack([_quat.stack(batched(x, B), axis=-1) for x in tgt], axis=-2)  # (*B, E, 3)
    err = _quat.safe_norm(_quat.unstack(take(P, eff) - t, axis=-1))
    ok = jnp.all(err <= tol, axis=-1)
    ang = None
    if orient is not None:
        Tq = jnp.stack([_quat.stack(batched(q, B), axis=-1) for q in orient.rotations], axis=-2)
        ang = angle_errors(G, eff, Tq)
        ok = ok & jnp.all(jnp.stack(orient.weights) * ang <= tol, axis=-1)

    return IKResult(rotations=jnp.moveaxis(L, (-2, -1), (0, 1)), positions=jnp.moveaxis(P, (-2, -1), (0, 1)),
                    error=jnp.moveaxis(err, -1, 0), iterations=iters, converged=ok, reachable=reachable, trace=errs,
                    angle_error=None if ang is None else jnp.moveaxis(ang, -1, 0))
