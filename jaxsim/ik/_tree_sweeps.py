"""CCD and FABRIK sweeps on joint trees with several end effectors.

Both work on per-joint lists of component tuples (the batch trails), unrolled over the
static tree; only the joints on some root-to-effector path (``Topology.active``) are
carried, and a joint with no effector below it never changes its local rotation.

**FABRIK** (Aristidou & Lasenby 2011, §4.2).  Backward pass, leaves to root: each active
joint is placed at the weighted centroid of its proposals: its target if it is an
effector, and, from each active child branch, the point at the bone's length from that
child towards the joint (a sub-base takes the centroid of its branches).  Forward pass,
root to leaves: a joint with one active child places it on the line to its backward
position, as on a chain; a sub-base with several active children turns its whole frame
by the rotation that best aligns its child bones with the directions to their backward
positions (Horn 1987, see ``_horn``), so the bones leaving a joint stay rigid and the
pose stays representable by local rotations.

**CCD.**  Tip to root, each joint with effectors below it turns its subtree by the
rotation minimising the weighted squared distance of those effectors to their targets:
the shortest arc when there is one effector below, Horn's rotation when there are more.
"""

from __future__ import annotations

import jax.numpy as jnp

from . import _quat
from ._horn import best_rotation
from ._limits import about, best_angle, clamp_range, hinge_angle, project


def branch_weights(topo, w):
    """Per joint, the summed effector weight of its subtree (``None`` off the active tree)."""
    J = len(topo.parents)
    W = [None] * J
    for i in topo.active:
        ks = list(topo.below[i]) + ([topo.effector_slot[i]] if topo.effector_slot[i] >= 0 else [])
        W[i] = sum(w[k] for k in ks)
    return W


def _place(moving, anchor, length, fallback):
    """``anchor + length * (moving - anchor) / |moving - anchor|``; along the unit vector
    ``fallback`` where the two coincide (NaN-free in value and gradient there)."""
    return _quat.add(anchor, _quat.scale(length, _quat.normalize(_quat.sub(moving, anchor), fallback)))


def _centroid(points, weights):
    if len(points) == 1:
        return points[0]
    tot = sum(weights)
    return tuple(sum(wk * p[c] for p, wk in zip(points, weights)) / tot for c in range(3))


def _backward(topo, lengths, P, targets, w, W, fallback):
    """FABRIK's backward pass: per active joint its backward position (the root's is unused)."""
    ac = topo.active_children
    Q = list(P)
    for i in reversed(topo.active[1:]):
        k = topo.effector_slot[i]
        pts = [targets[k]] if k >= 0 else []
        wts = [w[k]] if k >= 0 else []
        for c in ac[i]:
            pts.append(_place(P[i], Q[c], lengths[c], fallback))
            wts.append(W[c])
        Q[i] = _centroid(pts, wts)
    return Q


def fabrik_tree_sweep(topo, offsets, lengths, P, Gb, targets, w, W, fallback):
    """One backward + forward pass.

    Args:
      topo: ``Topology``.
      offsets: ``(J, 3)``; lengths: ``(J,)`` bone lengths (``lengths[0]`` unused).
      P: list of ``J`` positions (``None`` off the active tree); ``P[0]`` is the root.
      Gb: list of ``J`` global frames, set at sub-bases (several active children) only.
      targets: list of ``E`` vector tuples; w: ``(E,)`` weights; W: :func:`branch_weights`.
      fallback: unit vector tuple, the direction used where two joints coincide.

    Returns:
      ``(P, Gb, sq_errors)``: the new positions and sub-base frames, and the list of
      ``E`` squared effector errors of the returned pose.
    """
    ac = topo.active_children
    Q = _backward(topo, lengths, P, targets, w, W, fallback)
    N, G = list(P), list(Gb)
    for i in topo.active:
        kids = ac[i]
        if len(kids) == 1:
            c = kids[0]
            N[c] = _place(Q[c], N[i], lengths[c], fallback)
        elif len(kids) > 1:
            bones = [_quat.rotate(Gb[i], _quat.unstack(offsets[c])) for c in kids]
            r = best_rotation(bones, [_quat.sub(Q[c], N[i]) for c in kids], [W[c] for c in kids])
            G[i] = _quat.renormalize(_quat.mul(r, Gb[i]))
            for c in kids:
                N[c] = _quat.add(N[i], _quat.rotate(G[i], _quat.unstack(offsets[c])))
    err = [_quat.sqnorm(_quat.sub(N[e], t)) for e, t in zip(topo.effectors, targets)]
    return N, G, err


def _local(gp, g):
    return _quat.renormalize(g if gp is None else _quat.mul(_quat.conj(gp), g))


def _limited(table, i, q):
    return q if table is None or table.kinds[i] == "free" else project(q, *table.joint(i))


def fabrik_tree_sweep_frames(topo, offsets, lengths, P, L, targets, w, W, fallback, table, orient):
    """One FABRIK sweep that carries local rotations and keeps them within the joint limits.

    The backward pass is :func:`fabrik_tree_sweep`'s.  The forward pass (root to leaves)
    turns each joint's frame onto the backward positions of its active children (the
    shortest arc for one child, Horn's rotation for several), then projects the joint's
    local rotation onto its limit set before placing the children: the paper's
    constraint step (§4.1), which keeps the bone in its parent's allowed cone or plane
    and the twist in range.  An effector with no active joint below takes its target
    orientation (when given) projected onto its limits; an effector's orientation does
    not steer the positions (FABRIK is positional; CCD and LM weigh both).

    Args:
      P: list of positions (active joints); L: list of ``J`` local rotations (active
        joints; others are never read).  table: ``LimitTable`` or ``None``.
      orient: ``None`` or ``(rotations, weights)``: ``E`` target quaternion tuples and
        ``(E,)`` weights (scene units per radian).
      Other arguments as for :func:`fabrik_tree_sweep`.

    Returns:
      ``(P, L, sq_errors)``; the errors are :func:`effector_sq_errors` of the new pose.
    """
    parents, ac = topo.parents, topo.active_children
    Q = _backward(topo, lengths, P, targets, w, W, fallback)
    N, Lnew, g = list(P), list(L), [None] * len(parents)
    for i in topo.active:
        gp = g[parents[i]] if i > 0 else None
        cand = L[i] if gp is None else _quat.mul(gp, L[i])
        kids = ac[i]
        if len(kids) == 1:
            c = kids[0]
            bone = _quat.rotate(cand, _quat.unstack(offsets[c]))
            gi = _quat.mul(_quat.from_two_vectors(bone, _quat.sub(Q[c], N[i])), cand)
            if table is not None and table.kinds[c] == "hinge" and len(ac[c]) == 1:
                gi = _aim_hinge(gi, offsets, N[i], c, Q[ac[c][0]], table)
        elif len(kids) > 1:
            a = [_quat.rotate(cand, _quat.unstack(offsets[c])) for c in kids]
            b = [_quat.sub(Q[c], N[i]) for c in kids]
            wts = [W[c] for c in kids]
            for c in kids:  # a hinge child: also turn its axis onto the normal of the bend it must make
                if table is not None and table.kinds[c] == "hinge" and len(ac[c]) == 1:
                    _, ax, lo, hi, _ = table.joint(c)
                    zero = jnp.zeros_like(N[i][0])
                    bc = _quat.normalize(_quat.sub(Q[c], N[i]), (zero, zero, zero + 1.0))
                    v = _quat.normalize(_quat.sub(Q[ac[c][0]], Q[c]), bc)
                    a.append(_quat.scale(lengths[c], _quat.rotate(cand, ax)))
                    b.append(_quat.scale(jnp.where(lo + hi >= 0, lengths[c], -lengths[c]), _quat.cross(bc, v)))
                    wts.append(W[c])
            gi = _quat.mul(best_rotation(a, b, wts), cand)
        else:
            gi = orient[0][topo.effector_slot[i]] if orient is not None else cand
        Lnew[i] = _limited(table, i, _local(gp, gi))
        g[i] = Lnew[i] if gp is None else _quat.renormalize(_quat.mul(gp, Lnew[i]))
        for c in kids:
            N[c] = _quat.add(N[i], _quat.rotate(g[i], _quat.unstack(offsets[c])))
    return N, Lnew, effector_sq_errors(topo, N, g, targets, orient)


def _aim_hinge(gi, offsets, base, c, goal, table):
    """Twist the frame ``gi`` of joint ``c``'s parent about the bone to ``c`` so that ``c``'s
    hinge can bend its bone towards ``goal`` (the next backward position): the hinge axis
    is turned onto ``±(bone x (goal - c))``, the sign that bends into the hinge's range.

    Without this a straight limb whose parent has the wrong twist cannot bend at all: the
    shortest arc never turns the hinge plane.
    """
    _, ax, lo, hi, _ = table.joint(c)
    zero = jnp.zeros_like(gi[0])
    b = _quat.normalize(_quat.rotate(gi, _quat.unstack(offsets[c])), (zero, zero, zero + 1.0))
    v = _quat.sub(goal, _quat.add(base, _quat.rotate(gi, _quat.unstack(offsets[c]))))
    aw = _quat.rotate(gi, ax)
    a_perp = _quat.sub(aw, _quat.scale(_quat.dot(aw, b), b))
    d = _quat.scale(jnp.where(lo + hi >= 0, 1.0, -1.0), _quat.cross(b, v))
    return _quat.renormalize(_quat.mul(about(best_angle(b, [a_perp], [d], [1.0]), b), gi))


def effector_sq_errors(topo, P, G, targets, orient):
    """Per effector, ``max(|p - t|, weight * angle)^2`` (just ``|p - t|^2`` without orientations)."""
    err = [_quat.sqnorm(_quat.sub(P[e], t)) for e, t in zip(topo.effectors, targets)]
    if orient is None:
        return err
    rots, ow = orient
    return [jnp.maximum(e2, (ow[k] * _quat.angle(_quat.mul(_quat.conj(rots[k]), G[e]))) ** 2)
            for k, (e, e2) in enumerate(zip(topo.effectors, err))]


def fabrik_tree_rotations(topo, offsets, local0, P, Gb):
    """Local rotations whose FK reproduces the FABRIK positions ``P``, changed least from ``local0``.

    Root to leaves: a joint with one active child turns its candidate frame (its
    parent's new frame times its old local rotation) by the shortest arc onto its child
    bone, as for chains; a sub-base takes its frame ``Gb``; every other joint keeps its
    local rotation exactly.
    """
    parents, J = topo.parents, len(topo.parents)
    g, L = [None] * J, list(local0)
    for i in range(J):
        gp = g[parents[i]] if i > 0 else None
        cand = local0[i] if gp is None else _quat.mul(gp, local0[i])
        kids = topo.active_children[i]
        if len(kids) == 1:
            c = kids[0]
            bone_now = _quat.rotate(cand, _quat.unstack(offsets[c]))
            gi = _quat.renormalize(_quat.mul(_quat.from_two_vectors(bone_now, _quat.sub(P[c], P[i])), cand))
        elif len(kids) > 1:
            gi = Gb[i]
        else:
            g[i] = cand
            continue
        g[i] = gi
        L[i] = _quat.renormalize(gi if gp is None else _quat.mul(_quat.conj(gp), gi))
    return L


_AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def ccd_tree_sweep(topo, offsets, G, targets, w, root, table=None, orient=None):
    """One CCD sweep on the global frames of the active joints.

    Args:
      topo: ``Topology``; offsets: ``(J, 3)``.
      G: list of ``J`` global frames (``None`` off the active tree).
      targets: list of ``E`` vector tuples; w: ``(E,)`` weights; root: vector tuple.
      table: ``LimitTable`` or ``None``: each joint's new local rotation is projected
        onto its limit set, and the subtree turns by what the limit allows.
      orient: ``None`` or ``(rotations, weights)`` as in :func:`fabrik_tree_sweep_frames`.
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
                b.append(_quat.rotate(orient[0][k], u))
                wts.append(0.5 * w[k] * orient[1][k] ** 2)
        gp = G[parents[i]] if i > 0 else None
        if table is not None and table.kinds[i] == "hinge":  # the best turn about the hinge, clamped
            kind, ax, lo, hi, _ = table.joint(i)
            n = ax if gp is None else _quat.rotate(gp, ax)
            phi = hinge_angle(_local(gp, G[i]), ax)
            r = about(clamp_range(phi + best_angle(n, a, b, wts), lo, hi) - phi, n)
        else:
            r = _quat.from_two_vectors(a[0], b[0]) if len(a) == 1 else best_rotation(a, b, wts)
            if table is not None and table.kinds[i] != "free":
                loc = _limited(table, i, _local(gp, _quat.mul(r, G[i])))
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


def moving_joints(topo, orient: bool) -> tuple:
    """Joints a solver may turn: an effector strictly below, or (with orientation targets) an effector."""
    return topo.moving if not orient else tuple(sorted(set(topo.moving) | set(topo.effectors)))


def ccd_tree_rotations(topo, local0, G, table=None, orient=False):
    """Local rotations of the frames ``G``: ``L_i = G_p^{-1} G_i`` where joint ``i`` may have
    moved (projected onto its limits, which removes rounding drift), ``local0`` exactly elsewhere."""
    L = list(local0)
    for i in moving_joints(topo, orient):
        L[i] = _limited(table, i, _local(None if i == 0 else G[topo.parents[i]], G[i]))
    return L
