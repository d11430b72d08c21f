"""Self-contact in the step's potential: IPC's barrier on every point–triangle and
edge–edge pair closer than ``dhat`` (Li et al. 2020, §4), with the edge–edge mollifier.

A pair of primitives that share a vertex is left out.  Each pair adds
``kappa m_pair b(d, dhat)`` (times the mollifier for edges), with ``b`` and ``kappa`` those
of the colliders (``_implicit.contact``) and ``m_pair`` the mean mass of its four
particles.  The pairs come from the broadphase (``_self.broadphase``) over boxes that
hold each primitive along a straight motion, inflated by ``dhat / 2``, and a pair is kept
only if its distance can fall below ``dhat`` on that motion: ``d0 - l_p <= dhat``, with
``l_p`` the bound on the pair's relative motion of additive CCD (``_self.ccd``).  So a
set found for the motion from ``x`` to ``x + dx`` holds every pair the barrier sees
anywhere on that segment, and no other pair's barrier can be nonzero there.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..._dataclass import pytree_dataclass, static_field
from .._implicit.contact import _d, barrier, barrier_slope
from ..._fusion import materialized
from .._rank_one import RankOne, compacted
from . import broadphase as bp
from . import ccd
from .distance import columns, mollifier_soa, pair_distance2, point_triangle2, segment_segment2


#: Slots for box pairs per triangle (point–triangle) and per edge (edge–edge), before the
#: narrow phase keeps those that can come within ``dhat``; two 32x32 layers moving 5 cm
#: apart along their normal have 3.0 and 6.3 per triangle and edge.
BOX_SLOTS = 12


#: The pairs' Hessian blocks are applied in chunks of this many rows, up to the last pair
#: whose barrier acts (``_rank_one.RankOne.matvec``): a few hundred of the ``2 x 8 N`` slots
#: act in a drape of two layers, and PCG applies the blocks once per iteration.
PAIR_CHUNK = 256


@pytree_dataclass
class PairSet:
    """The point–triangle and edge–edge pairs the barrier sees on one motion.

    Attributes:
      pt: ``(P, 4)`` int32 particle ids ``(point, a, b, c)``.
      ee: ``(Q, 4)`` int32 particle ids ``(a0, a1, b0, b1)``.
      pt_on, ee_on: ``(P,)``, ``(Q,)`` bool, the slot holds a pair.
      overflow: ``()`` bool, more pairs than slots (some are missing: the step is not converged).
    """

    pt: jax.Array
    ee: jax.Array
    pt_on: jax.Array
    ee_on: jax.Array
    overflow: jax.Array


@pytree_dataclass
class SelfContact:
    """A step's self-contact data.

    Attributes:
      faces: ``(F, 3)`` int32 particle ids of the contact triangles.
      edges: ``(E, 2)`` int32 particle ids of their edges.
      rest: ``(N, 3)`` rest positions (m), for the mollifier's threshold.
      weight: ``(N,)`` ``kappa m_i`` per particle (N/m).
      dhat: ``()`` barrier distance (m).
      capacity: static slots per pair kind (``Cloth.self_contact_pairs``).
      pairs: the set in use, or ``None``: the pairs at the point evaluated.
    """

    faces: jax.Array
    edges: jax.Array
    rest: jax.Array
    weight: jax.Array
    dhat: jax.Array
    capacity: int = static_field(default=0)
    pairs: PairSet | None = None


def build(cloth, kappa) -> SelfContact:
    """The scene's :class:`SelfContact` with barrier stiffness ``kappa`` (1/s^2)."""
    return SelfContact(jnp.asarray(cloth.contact_faces), jnp.asarray(cloth.contact_edges), cloth.rest,
                       kappa * cloth.mass, cloth.contact_gap, cloth.self_contact_pairs)


def _boxes(ids, x, dx, pad):
    lo = jnp.min(x[ids], axis=1)
    hi = jnp.max(x[ids], axis=1)
    if dx is not None:
        y = x + dx
        lo = jnp.minimum(lo, jnp.min(y[ids], axis=1))
        hi = jnp.maximum(hi, jnp.max(y[ids], axis=1))
    return lo - pad, hi + pad


def _pt_dist2(x, ids):
    return point_triangle2(x[ids[:, 0]], x[ids[:, 1]], x[ids[:, 2]], x[ids[:, 3]])


def _ee_dist2(x, ids):
    return segment_segment2(x[ids[:, 0]], x[ids[:, 1]], x[ids[:, 2]], x[ids[:, 3]])


def pairs(sc: SelfContact, x, dx=None) -> PairSet:
    """The pairs closer than ``dhat`` anywhere on the motion from ``x`` to ``x + dx`` (both
    ``(N, 3)``; without ``dx``, at ``x``).  Nothing here is differentiated."""
    x = jax.lax.stop_gradient(x)
    dx = None if dx is None else jax.lax.stop_gradient(dx)
    F, E = sc.faces, sc.edges
    pad = 0.5 * sc.dhat
    cap = sc.capacity
    N = x.shape[0]
    pts = jnp.arange(N, dtype=jnp.int32)[:, None]
    lo_p, hi_p = _boxes(pts, x, dx, pad)
    lo_f, hi_f = _boxes(F, x, dx, pad)
    lo_e, hi_e = _boxes(E, x, dx, pad)
    # box pairs, before the narrow phase: in a cloth's own plane many boxes touch
    pt = bp.overlapping(lo_p, hi_p, lo_f, hi_f, BOX_SLOTS * F.shape[0], pts, F)
    ee = bp.overlapping(lo_e, hi_e, lo_e, hi_e, BOX_SLOTS * E.shape[0], E, E, same=True)

    # the narrow phase: only pairs whose distance can reach dhat on the motion
    def near(ids, dist2, split):
        d = jnp.sqrt(dist2(x, ids)) - (0.0 if dx is None else ccd.reach(dx[ids], split))
        return ids, d <= sc.dhat

    pt2 = bp.kept(pt, lambda a, b: near(jnp.concatenate([a[:, None], F[b]], axis=1), _pt_dist2, 1), cap, 4)
    ee2 = bp.kept(ee, lambda a, b: near(jnp.concatenate([E[a], E[b]], axis=1), _ee_dist2, 2), cap, 4)
    return PairSet(pt2.a, ee2.a, pt2.on, ee2.on, pt2.overflow | ee2.overflow)


def empty_pairs(sc: SelfContact) -> PairSet:
    """A :class:`PairSet` with no pairs, marked overflowing (a loop's first carry)."""
    P = sc.capacity
    z = jnp.zeros((P, 4), jnp.int32)
    off = jnp.zeros((P,), bool)
    return PairSet(z, z, off, off, jnp.array(True))


def current(sc: SelfContact, x) -> PairSet:
    """The set in use, or the pairs at ``x`` when none is set."""
    return pairs(sc, x) if sc.pairs is None else sc.pairs


def _pair_distance(sc: SelfContact, kind: int, X, ids):
    """``(d (P,), w (P,))``: the pairs' distances (m) and the factor ``kappa m_pair`` (times
    the mollifier for edges) on their barriers (N/m); ``X (P, 4, 3)``, ``ids (P, 4)``,
    ``kind`` 0 point–triangle, 1 edge–edge."""
    w = jnp.mean(sc.weight[ids], axis=1)
    d2 = pair_distance2(kind, X)
    if kind == 1:
        v = columns(X)
        r = sc.rest[ids]
        ea, eb = r[:, 1] - r[:, 0], r[:, 3] - r[:, 2]
        w = w * mollifier_soa(*v, 1e-3 * jnp.sum(ea * ea, axis=1) * jnp.sum(eb * eb, axis=1))
    pos = d2 > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, d2, 1.0)), 0.0), w


def _pair_energy(sc: SelfContact, kind: int, X, ids):
    """``(P,)`` the pairs' barriers (J)."""
    d, w = _pair_distance(sc, kind, X, ids)
    return w * barrier(d, sc.dhat)


def _stand_in(X, on):
    """``X (P, 4, 3)`` where ``on``, elsewhere four far-apart points (finite derivatives)."""
    far = jnp.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], X.dtype) * 1e3
    return jnp.where(on[:, None, None], X, far)


def _kinds(s: PairSet, x, free):
    """``(kind, ids (P, 4), moves (P,), X (P, 4, 3))`` for the point–triangle (kind 0) and
    edge–edge (1) pairs of ``s`` at ``x``: ``moves``, the slot holds a pair with a free
    particle (a pair of pins only adds a constant); ``X``, its positions (a stand-in elsewhere)."""
    for kind, ids, on in ((0, s.pt, s.pt_on), (1, s.ee, s.ee_on)):
        moves = on & jnp.any(free[ids, 0] > 0, axis=1)
        yield kind, ids, moves, _stand_in(x[ids], moves)


def potential_and_forces(sc: SelfContact, x, free):
    """``(barrier (J), forces (N,))`` at positions ``x (N, 3)``; ``free (N, 1)``.

    The self-contact barrier (a pair of pinned particles only adds a constant, left out),
    and the sizes of the pairs' barrier forces at each particle (N): each pair's
    ``|w b'(d)|`` at its four particles (a bound: ``|grad d| <= 1`` per particle), zero on
    pins.  One pass over the pairs' distances serves both (and, under ``jax.value_and_grad``,
    the gradient too: ``_implicit.parts.contact_parts``)."""
    s = current(sc, x)
    total = jnp.zeros((), x.dtype)
    out = jnp.zeros(x.shape[:1], x.dtype)
    for kind, ids, moves, X in _kinds(s, x, free):
        d, w = _pair_distance(sc, kind, X, ids)
        total = total + jnp.sum(jnp.where(moves, w * barrier(d, sc.dhat), 0.0))
        f = jnp.where(moves, -w * barrier_slope(d, sc.dhat), 0.0)
        out = out.at[ids].add(jnp.broadcast_to(f[:, None], ids.shape))
    return total, out * free[:, 0]


def blocks(sc: SelfContact, x, free) -> RankOne:
    """The pairs' Hessian blocks at ``x (N, 3)``, in the Gauss–Newton form ``c g g^T``
    (``_rank_one.RankOne``, rank one and PSD).

    For the barrier ``w b(d)`` of a pair the block is ``w b''(d) grad d grad d^T`` plus
    ``w b'(d) Hess d`` (and, for edges, the mollifier's terms).  The first is PSD
    (``b'' > 0``); the rest is dropped, as the colliders' projection drops it
    (``_implicit.contact``), so the gradient stays exact and the Hessian is a PSD model
    of it.  ``g`` is ``grad d`` over the pair's four particles (0 on pins), ``c`` is
    ``w b''(d)``; the pairs whose barrier acts come first (``_rank_one.compacted``)."""
    s = current(sc, x)
    ids_all, g_all, c_all = [], [], []
    for kind, ids, moves, X in _kinds(s, x, free):
        (d, w), g = _pair_distance(sc, kind, X, ids), jax.grad(lambda Y: jnp.sum(_pair_distance(sc, kind, Y, ids)[0]))(X)
        b2 = _d(barrier, 2)(d, sc.dhat)
        c = jnp.where(moves, w * jnp.maximum(b2, 0.0), 0.0)
        mask = jnp.repeat(free[ids, 0] > 0, 3, axis=1)
        ids_all.append(ids)
        g_all.append(g.reshape(-1, 12) * mask)
        c_all.append(c)
    return compacted(RankOne(jnp.concatenate(ids_all), materialized(jnp.concatenate(g_all)), jnp.concatenate(c_all)),
                     PAIR_CHUNK)


def step_bound(sc: SelfContact, s: PairSet, x, dx, t_max, chunk: int = PAIR_CHUNK):
    """``()`` the largest fraction ``<= t_max`` of the step ``dx (N, 3)`` from ``x`` that no pair
    of ``s`` crosses (additive CCD).

    The pairs are taken ``chunk`` slots at a time, up to the last slot that holds a pair
    (the broadphase puts them first, ``broadphase.kept``): an empty slot's stand-in does
    not move and allows the whole step, so the bound is the one over every slot."""
    t = jnp.asarray(t_max, x.dtype)
    for ids, on, dist2, split in ((s.pt, s.pt_on, point_triangle2, 1), (s.ee, s.ee_on, segment_segment2, 2)):
        P = on.shape[0]
        rows = -(-P // chunk) * chunk
        ids, on = jnp.pad(ids, ((0, rows - P), (0, 0))), jnp.pad(on, (0, rows - P))
        used = jnp.max(jnp.where(on, jnp.arange(1, rows + 1), 0))

        def body(i, t, ids=ids, on=on, dist2=dist2, split=split):
            I, O = (jax.lax.dynamic_slice_in_dim(a, i * chunk, chunk) for a in (ids, on))
            D = jnp.where(O[:, None, None], dx[I], 0.0)
            return jnp.minimum(t, jnp.min(ccd.additive(_stand_in(x[I], O), D, dist2, split, t_max)))

        t = jax.lax.fori_loop(0, (used + chunk - 1) // chunk, body, t)
    return t
