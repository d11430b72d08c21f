"""Self-contact in the step's potential: IPC's barrier on every point–triangle and
edge–edge pair closer than ``dhat`` (Li et al. 2020, §4), with the edge–edge mollifier.

A pair of primitives that share a vertex is left out.  Each pair adds
``kappa m_pair b(d, dhat)`` (times the mollifier for edges), with ``b`` and ``kappa`` those
of the colliders (``_implicit.contact``) and ``m_pair`` the mean mass of its four
particles.  The pairs are those whose barrier can act on the motion at hand
(``_self.pairs``): a set found for the motion from ``x`` to ``x + dx`` holds every pair the
barrier sees anywhere on that segment, and no other pair's barrier can be nonzero there.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..._dataclass import pytree_dataclass, static_field
from .._barrier import _d, barrier, barrier_slope
from .._rank_one import RankOne
from .broadphase import append
from . import ccd
from .distance import columns, mollifier_soa, pair_distance2, point_triangle2, segment_segment2
from .pairs import PairSet, pairs


#: The pairs' Hessian blocks are applied in chunks of this many rows, up to the last pair
#: whose barrier acts (``_rank_one.RankOne.matvec``): a few hundred of the ``2 x 8 N`` slots
#: act in a drape of two layers, and PCG applies the blocks once per iteration.
PAIR_CHUNK = 256


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
        moves = _moves(ids, on, free)
        yield kind, ids, moves, _stand_in(x[ids], moves)


def _moves(ids, on, free):
    """``(P,)`` bool: the slot holds a pair with a free particle; ``ids (P, 4)``, ``on (P,)``."""
    return on & jnp.any(free[ids, 0] > 0, axis=1)


def _slots(sc: SelfContact, kind: int, ids, moves, X):
    """``(barrier (J), force sizes (P,))`` of the slots ``ids (P, 4)`` at positions ``X (P, 4,
    3)``: the barriers summed and each pair's ``|w b'(d)|``, over the slots where ``moves``
    (elsewhere the stand-in's, whose derivative is 0)."""
    d, w = _pair_distance(sc, kind, _stand_in(X, moves), ids)
    return (jnp.sum(jnp.where(moves, w * barrier(d, sc.dhat), 0.0)),
            jnp.where(moves, -w * barrier_slope(d, sc.dhat), 0.0))


def potential_and_forces(sc: SelfContact, x, free):
    """``(barrier (J), forces (N,))`` at positions ``x (N, 3)``; ``free (N, 1)``.

    The self-contact barrier (a pair of pinned particles only adds a constant, left out),
    and the sizes of the pairs' barrier forces at each particle (N): each pair's
    ``|w b'(d)|`` at its four particles (a bound: ``|grad d| <= 1`` per particle), zero on
    pins.  One pass over every slot of the pairs' distances serves both (and, under
    ``jax.value_and_grad``, the gradient too): the definition, differentiable to any
    order.  Newton sums the same terms over the slots in use only (:func:`summed`)."""
    s = current(sc, x)
    total = jnp.zeros((), x.dtype)
    out = jnp.zeros(x.shape[:1], x.dtype)
    for kind, ids, on in ((0, s.pt, s.pt_on), (1, s.ee, s.ee_on)):
        e, f = _slots(sc, kind, ids, _moves(ids, on, free), x[ids])
        total = total + e
        out = out.at[ids].add(jnp.broadcast_to(f[:, None], ids.shape))
    return total, out * free[:, 0]


def _over_pairs(s: PairSet, chunk: int, body, carry):
    """``carry`` through ``body(kind, ids (chunk, 4), on (chunk,), carry)`` over the slots of
    ``s``, ``chunk`` at a time, up to the last slot that holds a pair (the broadphase puts
    them first, ``broadphase.kept``): the work follows the pairs, not the capacity."""
    for kind, ids, on in ((0, s.pt, s.pt_on), (1, s.ee, s.ee_on)):
        P = on.shape[0]
        rows = -(-P // chunk) * chunk
        ids, on = jnp.pad(ids, ((0, rows - P), (0, 0))), jnp.pad(on, (0, rows - P))
        used = jnp.max(jnp.where(on, jnp.arange(1, rows + 1), 0))

        def step(i, c, kind=kind, ids=ids, on=on):
            return body(kind, *(jax.lax.dynamic_slice_in_dim(a, i * chunk, chunk) for a in (ids, on)), c)

        carry = jax.lax.fori_loop(0, (used + chunk - 1) // chunk, step, carry)
    return carry


def summed(sc: SelfContact, x, free, chunk: int = PAIR_CHUNK):
    """``(barrier (J), gradient (N, 3), forces (N,))``: :func:`potential_and_forces` and the
    barrier's gradient in ``x``, over the set in use (``sc.pairs``) ``chunk`` slots at a
    time up to its last pair, each chunk's gradient by autodiff of the same terms.  Not
    differentiable itself (a loop with a traced trip count): Newton's evaluations, whose
    inputs are fixed."""
    x, free = jax.lax.stop_gradient(x), jax.lax.stop_gradient(free)

    def body(kind, ids, on, c):
        total, grad, out = c
        moves = _moves(ids, on, free)
        (e, f), g = jax.value_and_grad(lambda X: _slots(sc, kind, ids, moves, X), has_aux=True)(x[ids])
        return total + e, grad.at[ids].add(g), out.at[ids].add(jnp.broadcast_to(f[:, None], ids.shape))

    z = jnp.zeros(x.shape[:1], x.dtype)
    total, grad, out = _over_pairs(sc.pairs, chunk, body, (jnp.zeros((), x.dtype), jnp.zeros_like(x), z))
    return total, grad, out * free[:, 0]


def blocks(sc: SelfContact, x, free, chunk: int = PAIR_CHUNK) -> RankOne:
    """The pairs' Hessian blocks at ``x (N, 3)``, in the Gauss–Newton form ``c g g^T``
    (``_rank_one.RankOne``, rank one and PSD).

    For the barrier ``w b(d)`` of a pair the block is ``w b''(d) grad d grad d^T`` plus
    ``w b'(d) Hess d`` (and, for edges, the mollifier's terms).  The first is PSD
    (``b'' > 0``); the rest is dropped, as the colliders' projection drops it
    (``_implicit.contact``), so the gradient stays exact and the Hessian is a PSD model
    of it.  ``g`` is ``grad d`` over the pair's four particles (0 on pins), ``c`` is
    ``w b''(d)``.  The pairs are taken ``chunk`` slots at a time up to the last pair, and
    those whose barrier acts written first, in order, then zero rows (``RankOne.count``)."""
    s = current(sc, x)
    rows = -(-2 * s.pt_on.shape[0] // chunk) * chunk

    def body(kind, ids, on, c):
        outs, count = c
        moves = _moves(ids, on, free)
        X = _stand_in(x[ids], moves)
        (d, w), g = _pair_distance(sc, kind, X, ids), jax.grad(lambda Y: jnp.sum(_pair_distance(sc, kind, Y, ids)[0]))(X)
        cc = jnp.where(moves, w * jnp.maximum(_d(barrier, 2)(d, sc.dhat), 0.0), 0.0)
        g = g.reshape(-1, 12) * jnp.repeat(free[ids, 0] > 0, 3, axis=1)
        return append(outs, (ids, g, cc), cc != 0, count)

    outs = (jnp.zeros((rows, 4), jnp.int32), jnp.zeros((rows, 12), x.dtype), jnp.zeros((rows,), x.dtype))
    (ids, g, c), count = _over_pairs(s, chunk, body, (outs, jnp.int32(0)))
    return RankOne(ids, g, c, count, chunk)


def step_bound(sc: SelfContact, s: PairSet, x, dx, t_max, chunk: int = PAIR_CHUNK):
    """``()`` the largest fraction ``<= t_max`` of the step ``dx (N, 3)`` from ``x`` that no pair
    of ``s`` crosses (additive CCD), over its slots ``chunk`` at a time up to the last pair:
    an empty slot's stand-in does not move and allows the whole step, so the bound is the
    one over every slot."""

    def body(kind, ids, on, t):
        D = jnp.where(on[:, None, None], dx[ids], 0.0)
        dist2, split = (point_triangle2, 1) if kind == 0 else (segment_segment2, 2)
        return jnp.minimum(t, jnp.min(ccd.additive(_stand_in(x[ids], on), D, dist2, split, t_max)))

    return _over_pairs(s, chunk, body, jnp.asarray(t_max, x.dtype))
