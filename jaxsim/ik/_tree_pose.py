"""A tree pose as a solver result: bone lengths, reachability and the ``IKResult`` of local rotations."""

from __future__ import annotations

import jax.numpy as jnp

from . import _quat
from ._result import IKResult
from ._tree_fk import fk_tree


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


def finish(topo, offsets, local, tgt, orient, tol, iters, reachable, errs):
    """The component-first ``IKResult`` of the local rotations ``local`` (lists of tuples)."""
    P, G = fk_tree(topo.parents, offsets, local)
    err = jnp.stack([_quat.safe_norm(_quat.sub(P[e], t)) for e, t in zip(topo.effectors, tgt)])
    ok = jnp.all(err <= tol, axis=0)
    ang = None
    if orient is not None:
        ang = jnp.stack([_quat.angle(_quat.mul(_quat.conj(orient[0][k]), G[e])) for k, e in enumerate(topo.effectors)])
        ok = ok & jnp.all(jnp.stack(orient[1])[(...,) + (None,) * (ang.ndim - 1)] * ang <= tol, axis=0)
    B = jnp.shape(iters)
    return IKResult(rotations=_quat.stack([_quat.stack(q) for q in local]),
                    positions=_quat.stack([_quat.stack(batched(p, B)) for p in P]),
                    error=err, iterations=iters, converged=ok, reachable=reachable, trace=errs, angle_error=ang)
