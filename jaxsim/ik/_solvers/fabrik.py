"""FABRIK (Aristidou & Lasenby 2011): positions first, rotations rebuilt after, on any tree.

One sweep is a backward pass (pin each effector on its target, walk to the root) and a
forward pass (pin the root, walk to the effectors); each step puts a joint on the line
to its neighbour at the bone's length (Algorithm 1, §4.1).  On a tree (§4.2) a joint
takes the weighted centroid of its branches' proposals in the backward pass, and in
the forward pass a sub-base with several active children turns its frame by the
rotation that best aligns its child bones (Horn 1987, ``jaxsim._geometry.horn``), so bones leaving a
joint stay rigid; with joint limits each joint's local rotation is projected onto its
limit set (§4.1's constraint step, :func:`fabrik_tree_sweep_frames`).

A chain solved for its end takes the lean kernels (:func:`chain_plan`): the backward and
forward passes on per-joint lists (or a rolled ``fori_loop``), and an unreachable
target answered up front by the paper's straight line towards it (one sweep).
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np
from jax import lax

from ..._dataclass import pytree_dataclass
from ..._dtype import tiny
from ..._geometry import quat as _quat
from .._model import joints as _joints
from ..._geometry.horn import best_rotation
from .._model.projection import about, best_angle
from .loop import SweepPlan
from .._model.pose import batched, effector_sq_errors, limited, local_of
from .._model.stacked import batch_leading, take, tree_levels


def chain_plan(s) -> SweepPlan:
    """The lean chain sweeps on a ``kernel.ChainStart`` ``s``.

    An unreachable target gets the straight chain towards it: those elements start the
    loop done, with that sweep counted.  Where two joints coincide, a bone takes one
    direction per chain, perpendicular to the rest chain (a per-target direction would
    be three more arrays read by every joint update of the batched sweep).
    """
    J, B, tgt, root = s.offsets.shape[0], s.batch, s.target, s.root
    fallback = _quat.perpendicular(_quat.unstack(jnp.sum(s.offsets[1:], axis=0)))
    straight = straight_towards(root, tgt, s.lengths, fallback)
    jump = ~s.reachable & ~s.done
    err0 = jnp.where(jump, _quat.safe_norm(_quat.sub(straight[J - 1], tgt)), s.err)
    if s.unroll:  # the lean batched sweep on joints 1..J-1 (the root never moves)
        state0 = [batched(_quat.where(jump, st, p), B) for st, p in zip(straight[1:], s.positions[1:])]
        bias = _quat.scale(tiny(s.offsets.dtype), fallback)

        def sweep(state):
            new = fabrik_sweep_lean(state, tgt, root, s.lengths, bias)
            return new, _quat.sqnorm(_quat.sub(new[-1], tgt))

        def rotations(state):
            return [batched(q, B) for q in rotations_from_positions(s.offsets, s.local, [root] + list(state), B,
                                                                     unroll=True)]
    else:
        state0 = jnp.where(jump, _joints.stack(straight), s.positions)

        def sweep(state):
            new = fabrik_sweep(state, tgt, root, s.lengths, fallback, unroll=False)
            return new, _quat.sqnorm(_quat.sub(_joints.get(new, J - 1), tgt))

        def rotations(state):
            return rotations_from_positions(s.offsets, s.local, state, B, unroll=False)

    # The lean sweep keeps going on finished elements and returns a snapshot (one select
    # per sweep off the sweep's chain; see docs/notebook.md and benchmarks/ik_throughput.py).
    return SweepPlan(state0=state0, sweep=sweep, rotations=rotations, err0=err0, iters0=jump.astype(jnp.int32),
                     done0=s.done | ~s.reachable, freeze="snapshot" if s.unroll else "where")


@pytree_dataclass
class TreeState:
    """The tree sweeps' loop state (lists of ``J``, ``None`` off the active tree).

    Attributes:
      positions: joint positions (vector tuples over the batch).
      rotations: the framed sweep's local rotations of the active joints, or the plain
        sweep's global frames of the sub-bases (``None`` elsewhere).
    """

    positions: list
    rotations: list


def tree_plan(s) -> SweepPlan:
    """The tree sweeps on a ``kernel.TreeStart`` ``s``; with limits or orientation targets
    the sweeps carry local rotations (:func:`fabrik_tree_sweep_frames`) and the best pose
    visited is returned."""
    topo, B, J = s.topo, s.batch, len(s.topo.parents)
    act = set(topo.active)
    framed = s.table is not None or s.orient is not None
    W = branch_weights(topo, s.weights)
    dtype = s.offsets.dtype
    fallback = (jnp.zeros((), dtype), jnp.zeros((), dtype), jnp.ones((), dtype))
    subbase = [len(c) > 1 for c in topo.active_children]
    second = [batched(s.local[i] if framed else s.frames[i], B) if (framed or subbase[i]) and i in act else None
              for i in range(J)]
    state0 = TreeState([batched(s.positions[i], B) if i in act else None for i in range(J)], second)

    def sweep(st: TreeState):
        if framed:
            P, R, err = fabrik_tree_sweep_frames(topo, s.offsets, s.lengths, st.positions, st.rotations, s.targets,
                                                 s.weights, W, fallback, s.table, s.orient)
        else:
            P, R, err = fabrik_tree_sweep(topo, s.offsets, s.lengths, st.positions, st.rotations, s.targets, s.weights,
                                          W, fallback)
        return TreeState(P, R), functools.reduce(jnp.maximum, err)

    def rotations(st: TreeState):
        if framed:
            return batch_leading([st.rotations[i] if i in act else s.local[i] for i in range(J)], B)
        return fabrik_tree_rotations(topo, s.offsets, s.local, st.positions, st.rotations, B)

    return SweepPlan(state0=state0, sweep=sweep, rotations=rotations, err0=s.err, iters0=jnp.zeros(B, jnp.int32),
                     done0=s.done, keep_best=framed)


def fabrik_sweep(positions, target, root, lengths, fallback, *, unroll: bool):
    """One backward + forward pass on a chain's container of ``J`` positions (``joints``);
    ``lengths (J-1,)``; ``fallback``: the unit direction where two joints coincide."""
    J = lengths.shape[0] + 1

    def backward(i, P):
        child = _joints.get(P, i + 1)
        u = _quat.normalize(_quat.sub(_joints.get(P, i), child), fallback)
        return _joints.put(P, i, _quat.add(child, _quat.scale(lengths[i], u)))

    def forward(i, P):
        parent = _joints.get(P, i - 1)
        u = _quat.normalize(_quat.sub(_joints.get(P, i), parent), fallback)
        return _joints.put(P, i, _quat.add(parent, _quat.scale(lengths[i - 1], u)))

    P = _joints.put(positions, J - 1, target)
    P = _joints.loop(0, J - 1, backward, P, unroll=unroll, reverse=True)
    P = _joints.put(P, 0, root)
    return _joints.loop(1, J, forward, P, unroll=unroll)


def fabrik_sweep_lean(joints, target, root, lengths, bias):
    """:func:`fabrik_sweep` for large batches, on the list of joints ``1..J-1``.

    The root is not carried (the forward pass pins it), and each bone direction is
    ``d * rsqrt(d.d)`` with ``d`` offset by ``bias = tiny * fallback`` instead of a zero
    test and a ``where`` per joint: where two joints coincide the direction is the
    fallback, elsewhere the offset is far below rounding.  Returns the new list.
    """
    n = len(joints)
    new = list(joints)

    def place(moving, anchor, length):
        d = tuple(m - a + b for m, a, b in zip(moving, anchor, bias))
        s = length * lax.rsqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        return tuple(a + s * c for a, c in zip(anchor, d))

    nxt = new[n - 1] = target
    for i in range(n - 1, 0, -1):  # joint i (stored at i - 1), towards joint i + 1
        nxt = new[i - 1] = place(new[i - 1], nxt, lengths[i])
    prev = root
    for i in range(1, n + 1):  # joint i, from joint i - 1
        prev = new[i - 1] = place(new[i - 1], prev, lengths[i - 1])
    return new


def straight_towards(root, target, lengths, fallback):
    """Joint positions (a list of vector tuples) of the chain stretched from ``root`` towards ``target``."""
    ray = _quat.normalize(_quat.sub(target, root), fallback)
    out, acc = [root], 0.0
    for i in range(lengths.shape[0]):
        acc = acc + lengths[i]
        out.append(_quat.add(root, _quat.scale(acc, ray)))
    return out


def rotations_from_positions(offsets, local0, positions, batch_shape, *, unroll: bool):
    """A chain's local rotations (a container) whose FK reproduces ``positions``, changed
    least from ``local0`` (the containers the positions were started from).

    Down the chain, joint ``i``'s bone ``c = R(L0_i) o_{i+1}`` is turned by the shortest
    arc (:func:`_quat.arc_lean`, the half-turn about a perpendicular of ``c`` where
    opposite) onto the wanted bone in the parent's *new* frame,
    ``w = R(g_{i-1})^T (P_{i+1} - P_i)``: ``L_i = arc(c, w) L0_i``.  The end joint keeps
    its local rotation.
    """
    J = offsets.shape[0]
    ident = _quat.identity(batch_shape, offsets.dtype)

    def body(i, c):
        L, g_parent = c
        l0 = _joints.get(local0, i)
        bone_rest = _quat.rotate(l0, _quat.unstack(offsets[i + 1]))
        want = _quat.sub(_joints.get(positions, i + 1), _joints.get(positions, i))
        want = _quat.rotate(_quat.conj(g_parent), want)
        arc = _quat.arc_lean(bone_rest, want, _quat.perpendicular(bone_rest))
        local = _quat.renormalize(_quat.mul(arc, l0))
        return _joints.put(L, i, local), _quat.mul(g_parent, local)

    L, _ = _joints.loop(0, J - 1, body, (local0, ident), unroll=unroll)
    return L


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
      orient: ``OrientTargets`` or ``None``.
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
                    lim = table.joint(c)
                    ax, lo, hi = lim.axis, lim.lo, lim.hi
                    zero = jnp.zeros_like(N[i][0])
                    bc = _quat.normalize(_quat.sub(Q[c], N[i]), (zero, zero, zero + 1.0))
                    v = _quat.normalize(_quat.sub(Q[ac[c][0]], Q[c]), bc)
                    a.append(_quat.scale(lengths[c], _quat.rotate(cand, ax)))
                    b.append(_quat.scale(jnp.where(lo + hi >= 0, lengths[c], -lengths[c]), _quat.cross(bc, v)))
                    wts.append(W[c])
            gi = _quat.mul(best_rotation(a, b, wts), cand)
        else:
            gi = orient.rotations[topo.effector_slot[i]] if orient is not None else cand
        Lnew[i] = limited(table, i, local_of(gp, gi))
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
    lim = table.joint(c)
    ax, lo, hi = lim.axis, lim.lo, lim.hi
    zero = jnp.zeros_like(gi[0])
    b = _quat.normalize(_quat.rotate(gi, _quat.unstack(offsets[c])), (zero, zero, zero + 1.0))
    v = _quat.sub(goal, _quat.add(base, _quat.rotate(gi, _quat.unstack(offsets[c]))))
    aw = _quat.rotate(gi, ax)
    a_perp = _quat.sub(aw, _quat.scale(_quat.dot(aw, b), b))
    d = _quat.scale(jnp.where(lo + hi >= 0, 1.0, -1.0), _quat.cross(b, v))
    return _quat.renormalize(_quat.mul(about(best_angle(b, [a_perp], [d], [1.0]), b), gi))


def fabrik_tree_rotations(topo, offsets, local0, P, Gb, B):
    """Local rotations ``(*B, J, 4)`` whose FK reproduces the FABRIK positions ``P``, changed
    least from ``local0``.

    Root to leaves: a joint with one active child turns its candidate frame (its
    parent's new frame times its old local rotation) by the shortest arc onto its child
    bone, as for chains; a sub-base takes its frame ``Gb``; every other joint keeps its
    local rotation exactly.  One tree level at a time, its joints at once (``stacked``).
    """
    parents, ac = topo.parents, topo.active_children
    levels, _ = tree_levels(tuple(parents))
    L = batch_leading(local0, B)
    g_prev, rows = None, [((0,), None)] + list(levels)
    for joints, prow in rows:
        cand = take(L, joints)
        gp = None if prow is None else take(g_prev, prow)
        if gp is not None:
            cand = _quat.stack(_quat.mul(_quat.unstack(gp, axis=-1), _quat.unstack(cand, axis=-1)), axis=-1)
        g = cand
        one = [r for r, i in enumerate(joints) if len(ac[i]) == 1]
        if one:
            i1, c1 = [joints[r] for r in one], [ac[joints[r]][0] for r in one]
            c = _quat.unstack(take(cand, one), axis=-1)
            bone = _quat.rotate(c, _quat.unstack(take(offsets, c1, axis=0), axis=-1))
            want = _quat.unstack(batch_leading([P[k] for k in c1], B) - batch_leading([P[k] for k in i1], B), axis=-1)
            g = g.at[..., np.asarray(one), :].set(
                _quat.stack(_quat.renormalize(_quat.mul(_quat.from_two_vectors(bone, want), c)), axis=-1))
        sub = [r for r, i in enumerate(joints) if len(ac[i]) > 1]
        if sub:
            g = g.at[..., np.asarray(sub), :].set(batch_leading([Gb[joints[r]] for r in sub], B))
        moved = [r for r, i in enumerate(joints) if ac[i]]
        if moved:
            gm = _quat.unstack(take(g, moved), axis=-1)
            loc = gm if gp is None else _quat.mul(_quat.conj(_quat.unstack(take(gp, moved), axis=-1)), gm)
            L = L.at[..., np.asarray([joints[r] for r in moved]), :].set(_quat.stack(_quat.renormalize(loc), axis=-1))
        g_prev = g
    return L
