"""A pose as solver data: bone lengths, reachability, effector errors, and the ``IKResult``
of local rotations.  Shared by the sweep solvers and LM on any tree (a chain is one)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from .._geometry import quat as _quat
from ._fk import fk_tree
from ._projection import project
from ._result import IKResult


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


def finish(topo, offsets, local, tgt, orient: OrientTargets | None, tol, iters, reachable, errs):
    """The component-first ``IKResult`` of the local rotations ``local`` (lists of tuples)."""
    P, G = fk_tree(topo.parents, offsets, local)
    err = jnp.stack([_quat.safe_norm(_quat.sub(P[e], t)) for e, t in zip(topo.effectors, tgt)])
    ok = jnp.all(err <= tol, axis=0)
    ang = None
    if orient is not None:
        ang = jnp.stack([_quat.angle(_quat.mul(_quat.conj(orient.rotations[k]), G[e]))
                         for k, e in enumerate(topo.effectors)])
        ok = ok & jnp.all(jnp.stack(orient.weights)[(...,) + (None,) * (ang.ndim - 1)] * ang <= tol, axis=0)
    B = jnp.shape(iters)
    return IKResult(rotations=_quat.stack([_quat.stack(q) for q in local]),
                    positions=_quat.stack([_quat.stack(batched(p, B)) for p in P]),
                    error=err, iterations=iters, converged=ok, reachable=reachable, trace=errs, angle_error=ang)
