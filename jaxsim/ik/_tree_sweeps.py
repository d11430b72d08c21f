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

from . import _quat
from ._horn import best_rotation


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
    Q = list(P)
    for i in reversed(topo.active[1:]):
        k = topo.effector_slot[i]
        pts = [targets[k]] if k >= 0 else []
        wts = [w[k]] if k >= 0 else []
        for c in ac[i]:
            pts.append(_place(P[i], Q[c], lengths[c], fallback))
            wts.append(W[c])
        Q[i] = _centroid(pts, wts)
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


def ccd_tree_sweep(topo, offsets, G, targets, w, root):
    """One CCD sweep on the global frames of the active joints.

    Args:
      topo: ``Topology``; offsets: ``(J, 3)``.
      G: list of ``J`` global frames (``None`` off the active tree).
      targets: list of ``E`` vector tuples; w: ``(E,)`` weights; root: vector tuple.

    Returns:
      ``(G, sq_errors)``: the new frames (``G'_j = r_0 ... r_j G_j`` over the joints on
      the path to ``j``) and the ``E`` squared effector errors after the sweep.
    """
    parents, J = topo.parents, len(topo.parents)
    P = [None] * J
    for i in topo.active:
        P[i] = root if i == 0 else _quat.add(P[parents[i]], _quat.rotate(G[parents[i]], _quat.unstack(offsets[i])))
    E = [P[e] for e in topo.effectors]
    arcs = [None] * J
    for i in reversed(topo.moving):
        ks = topo.below[i]
        a = [_quat.sub(E[k], P[i]) for k in ks]
        b = [_quat.sub(targets[k], P[i]) for k in ks]
        r = _quat.from_two_vectors(a[0], b[0]) if len(ks) == 1 else best_rotation(a, b, [w[k] for k in ks])
        for k, ak in zip(ks, a):
            E[k] = _quat.add(P[i], _quat.rotate(r, ak))
        arcs[i] = r
    C, new = [None] * J, list(G)
    for i in topo.active:
        cp = C[parents[i]] if i > 0 else None
        C[i] = arcs[i] if cp is None else (cp if arcs[i] is None else _quat.mul(cp, arcs[i]))
        if C[i] is not None:
            new[i] = _quat.renormalize(_quat.mul(C[i], G[i]))
    err = [_quat.sqnorm(_quat.sub(e, t)) for e, t in zip(E, targets)]
    return new, err


def ccd_tree_rotations(topo, local0, G):
    """Local rotations of the frames ``G``: ``L_i = G_p^{-1} G_i`` where joint ``i`` may have
    moved, ``local0`` exactly elsewhere."""
    L = list(local0)
    for i in topo.moving:
        gi = G[i]
        L[i] = _quat.renormalize(gi if i == 0 else _quat.mul(_quat.conj(G[topo.parents[i]]), gi))
    return L
