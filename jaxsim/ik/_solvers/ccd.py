"""Cyclic coordinate descent (CCD) on any tree: one sweep, tip to root.

Each joint with effectors below it turns its subtree by the rotation minimising the
weighted squared distance of those effectors to their targets: the shortest arc from
the end effector onto the ray to the target when there is one effector below (Wang &
Chen 1991; the lab's CCD), Horn's (1987) rotation when there are more.  The local
rotation becomes ``L_i = G_{i-1}^{-1} * r * G_i``.  The global frames ``G`` come from FK
at the start of the sweep; a joint only changes frames below it, so ``G_{i-1}`` and
``G_i`` are still current when joint ``i`` is visited and only the effectors need
updating as the sweep goes up.

A chain solved for its end takes the lean kernels (:func:`chain_plan`): per-joint
containers, or for large batches the global frames alone (:func:`ccd_sweep_frames`).
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from ..._geometry import quat as _quat
from .._model import joints as _joints
from .._model.fk import fk_joints
from ..._geometry.horn import best_rotation
from .._model.projection import about, best_angle, clamp_range, hinge_angle
from .loop import SweepPlan
from .._model.pose import batched, effector_sq_errors, limited, local_of, moving_joints
from .._model.stacked import apply_bounds, batch_leading, bounds


def chain_plan(s) -> SweepPlan:
    """The lean chain sweeps on a ``kernel.ChainStart`` ``s``."""
    J, B, tgt = s.offsets.shape[0], s.batch, s.target
    if s.unroll:
        def sweep(frames):
            return ccd_sweep_frames(s.offsets, tgt, frames, s.root)

        state0 = [batched(g, B) for g in s.frames]

        def rotations(frames):
            return [batched(q, B) for q in locals_from_frames(frames)]
    else:
        def sweep(state):
            new = ccd_sweep(s.offsets, tgt, *state, B, unroll=False)
            return new, _quat.sqnorm(_quat.sub(_joints.get(new[1], J - 1), tgt))

        state0 = (s.local, s.positions, s.frames)

        def rotations(state):
            return state[0]
    return SweepPlan(state0=state0, sweep=sweep, rotations=rotations, err0=s.err, iters0=jnp.zeros(B, jnp.int32),
                     done0=s.done)


def tree_plan(s) -> SweepPlan:
    """The tree sweep on a ``kernel.TreeStart`` ``s``, on the active joints' global frames."""
    topo, B, J = s.topo, s.batch, len(s.topo.parents)
    act = set(topo.active)
    root = batched(_quat.unstack(s.offsets[0]), B)

    def sweep(G):
        G, err = ccd_tree_sweep(topo, s.offsets, G, s.targets, s.weights, root, s.table, s.orient)
        return G, functools.reduce(jnp.maximum, err)

    def rotations(G):
        return ccd_tree_rotations(topo, s.local, G, B, s.table, s.orient is not None)

    return SweepPlan(state0=[batched(s.frames[i], B) if i in act else None for i in range(J)], sweep=sweep,
                     rotations=rotations, err0=s.err, iters0=jnp.zeros(B, jnp.int32), done0=s.done,
                     keep_best=s.table is not None or s.orient is not None)


#: The batched sweep renormalises its frames by one Newton step (no ``rsqrt``, so XLA
#: fuses it with the products before it) from this many elements up, by ``rsqrt`` below
#: (the crossover measured in docs/notebook.md, "CCD renormalisation").
NEWTON_RENORM_MIN_BATCH = 4096


def ccd_sweep(offsets, target, local, positions, frames, batch_shape, *, unroll: bool):
    """One CCD sweep of a chain on its containers (``joints``) of local rotations,
    positions and frames; returns the three after the sweep (the last two by FK, so the
    loop's error is that of the returned pose)."""
    J = offsets.shape[0]
    ident = _quat.identity(batch_shape, offsets.dtype)

    def body(i, c):
        L, end = c
        p = _joints.get(positions, i)
        r = _quat.from_two_vectors(_quat.sub(end, p), _quat.sub(target, p))
        end = _quat.add(p, _quat.rotate(r, _quat.sub(end, p)))
        if unroll:
            g_parent = ident if i == 0 else frames[i - 1]
        else:
            g_parent = _quat.where(i > 0, _joints.get(frames, jnp.maximum(i - 1, 0)), ident)
        g = _quat.mul(r, _joints.get(frames, i))
        # renormalised so rounding cannot compound through FK over many sweeps
        L = _joints.put(L, i, _quat.renormalize(_quat.mul(_quat.conj(g_parent), g)))
        return L, end

    L, _ = _joints.loop(0, J - 1, body, (local, _joints.get(positions, J - 1)), unroll=unroll, reverse=True)
    P, G = fk_joints(offsets, L, batch_shape, unroll=unroll)
    return L, P, G


def ccd_sweep_frames(offsets, target, frames, root):
    """:func:`ccd_sweep` for large batches, on the list of ``J`` global frames alone.

    Positions come from the frames, the arcs ``r_i`` (:func:`_quat.arc_lean`) are taken
    tip to root while the end is swung along, and the new frames are
    ``G'_i = r_0 ... r_i G_i``; local rotations are rebuilt once, after the last sweep
    (:func:`locals_from_frames`).  Where the end and the target lie exactly opposite
    about a joint, that joint does not turn in this sweep.  Returns ``(frames,
    |end - target|^2)``.
    """
    J = offsets.shape[0]
    P = [root]
    for k in range(1, J):
        P.append(_quat.add(P[k - 1], _quat.rotate(frames[k - 1], _quat.unstack(offsets[k]))))
    end = P[J - 1]
    arcs = [None] * (J - 1)
    for i in range(J - 2, -1, -1):
        a = _quat.sub(end, P[i])
        arcs[i] = _quat.arc_lean(a, _quat.sub(target, P[i]))
        end = _quat.add(P[i], _quat.rotate(arcs[i], a))
    big = jnp.size(frames[0][0]) >= NEWTON_RENORM_MIN_BATCH  # the loop carries full-batch frames
    renorm = _quat.renormalize_near_unit if big else _quat.renormalize
    new, C = [], None
    for i in range(J - 1):
        C = arcs[i] if C is None else _quat.mul(C, arcs[i])
        new.append(renorm(_quat.mul(C, frames[i])))
    new.append(renorm(_quat.mul(C, frames[J - 1])))
    return new, _quat.sqnorm(_quat.sub(end, target))


def locals_from_frames(frames):
    """Local rotations ``L_0 = G_0``, ``L_i = G_{i-1}^{-1} G_i`` (renormalised) of a list of frames."""
    out = [_quat.renormalize(frames[0])]
    for i in range(1, len(frames)):
        out.append(_quat.renormalize(_quat.mul(_quat.conj(frames[i - 1]), frames[i])))
    return out


_AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def ccd_tree_sweep(topo, offsets, G, targets, w, root, table=None, orient=None):
    """One CCD sweep on the global frames of the active joints.

    Args:
      topo: ``Topology``; offsets: ``(J, 3)``.
      G: list of ``J`` global frames (``None`` off the active tree).
      targets: list of ``E`` vector tuples; w: ``(E,)`` weights; root: vector tuple.
      table: ``LimitTable`` or ``None``: each joint's new local rotation is projected
        onto its limit set, and the subtree turns by what the limit allows.
      orient: ``OrientTargets`` or ``None``.
        Each oriented effector adds its three frame axes as direction pairs of weight
        ``w_k weights_k^2 / 2`` to Horn's problem, so a joint minimises
        ``w_k (|p - t|^2 + weights_k^2 * 4 sin^2(angle / 2))``; the effector joint itself
        also turns.

    Returns:
      ``(G, sq_errors)``: the new frames (``G'_j = r_0 ... r_j G_j`` over the joints on
      the path to ``j``) and :func:`effector_sq_errors` after the sweep.
    """
    parents, J = topo.parents, len(topo.parents)
    P = [None] * J
    for i in topo.active:
        P[i] = root if i == 0 else _quat.add(P[parents[i]], _quat.rotate(G[parents[i]], _quat.unstack(offsets[i])))
    E = [P[e] for e in topo.effectors]
    F = None if orient is None else [G[e] for e in topo.effectors]
    arcs = [None] * J
    for i in reversed(moving_joints(topo, orient is not None)):
        ks = topo.below[i]
        ko = () if orient is None else ks + ((topo.effector_slot[i],) if topo.effector_slot[i] >= 0 else ())
        a = [_quat.sub(E[k], P[i]) for k in ks]
        b = [_quat.sub(targets[k], P[i]) for k in ks]
        wts = [w[k] for k in ks]
        for k in ko:
            for u in _AXES:
                a.append(_quat.rotate(F[k], u))
                b.append(_quat.rotate(orient.rotations[k], u))
                wts.append(0.5 * w[k] * orient.weights[k] ** 2)
        gp = G[parents[i]] if i > 0 else None
        if table is not None and table.kinds[i] == "hinge":  # the best turn about the hinge, clamped
            lim = table.joint(i)
            ax, lo, hi = lim.axis, lim.lo, lim.hi
            n = ax if gp is None else _quat.rotate(gp, ax)
            phi = hinge_angle(local_of(gp, G[i]), ax)
            r = about(clamp_range(phi + best_angle(n, a, b, wts), lo, hi) - phi, n)
        else:
            r = _quat.from_two_vectors(a[0], b[0]) if len(a) == 1 else best_rotation(a, b, wts)
            if table is not None and table.kinds[i] != "free":
                loc = limited(table, i, local_of(gp, _quat.mul(r, G[i])))
                r = _quat.mul(loc if gp is None else _quat.mul(gp, loc), _quat.conj(G[i]))
        for k, ak in zip(ks, a):
            E[k] = _quat.add(P[i], _quat.rotate(r, ak))
        for k in ko:
            F[k] = _quat.mul(r, F[k])
        arcs[i] = r
    C, new = [None] * J, list(G)
    for i in topo.active:
        cp = C[parents[i]] if i > 0 else None
        C[i] = arcs[i] if cp is None else (cp if arcs[i] is None else _quat.mul(cp, arcs[i]))
        if C[i] is not None:
            new[i] = _quat.renormalize(_quat.mul(C[i], G[i]))
    Ef = [None] * J
    for k, e in enumerate(topo.effectors):
        Ef[e] = E[k]
    return new, effector_sq_errors(topo, Ef, None if F is None else dict(zip(topo.effectors, F)), targets, orient)


def ccd_tree_rotations(topo, local0, G, B, table=None, orient=False):
    """Local rotations ``(*B, J, 4)`` of the frames ``G``: ``L_i = G_p^{-1} G_i`` where joint
    ``i`` may have moved (projected onto its limits, which removes rounding drift),
    ``local0`` exactly elsewhere; all joints at once (``stacked``)."""
    L = batch_leading(local0, B)
    mv = moving_joints(topo, orient)
    if not mv:
        return L
    ident = _quat.identity((), L.dtype)
    g = _quat.unstack(batch_leading([G[i] for i in mv], B), axis=-1)
    gp = _quat.unstack(batch_leading([G[topo.parents[i]] if i > 0 else ident for i in mv], B), axis=-1)
    L = L.at[..., np.asarray(mv), :].set(_quat.stack(_quat.renormalize(_quat.mul(_quat.conj(gp), g)), axis=-1))
    return apply_bounds(bounds(table, mv), L)
