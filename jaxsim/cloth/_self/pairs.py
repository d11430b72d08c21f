"""Which point–triangle and edge–edge pairs the barrier sees on a motion, and the
candidates they are drawn from, kept for every motion inside a region.

A pair can only act on the motion from ``x`` to ``x + dx`` if its distance can fall below
``dhat`` there: ``d(x) - l_p <= dhat``, with ``l_p`` additive CCD's bound on the pair's
relative motion (``_self.ccd.reach``), the narrow phase.  Its candidates are the pairs
whose boxes overlap (``_self.broadphase``), each box holding its primitive's vertices
over a *region*: per particle, the box ``[lo, hi]`` around the motion's segment, grown by
a margin.  A later motion whose segment stays in the region (both ends: the region is
convex) has every box inside the candidates' boxes, so the candidates hold every pair it
can bring within ``dhat``, and only the narrow phase runs again: Newton's later
iterations move a few millimetres, and one search serves several of them (a Verlet list;
IPC, Li et al. 2020, §5, searches on every line search).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..._dataclass import pytree_dataclass
from . import broadphase as bp
from . import ccd
from .distance import point_triangle2, segment_segment2

#: Box pairs per triangle (point–triangle) and per edge (edge–edge), before the narrow
#: phase keeps those that can come within ``dhat``: two 32x32 layers moving 5 cm apart
#: along their normal have 3.0 and 6.3 per triangle and edge.
BOX_SLOTS = 12

#: The region a search's candidates hold for: the motion's boxes grown by this many
#: ``dhat`` on every side (``margin``).
REGION = 1.0

#: A grown region also reaches this many motions further along the motion it was searched
#: for: Newton's next steps tend to go on the same way.  Two 32x32 layers' 30-step drop
#: searched 467 times in about 2,600 Newton iterations in float64 without it, 310 with 1
#: and 238 with 3 (float32: 398 and 242; docs/notebook.md, "the home-cell grid").
AHEAD = 3.0


@pytree_dataclass
class Candidates:
    """Box pairs found once, for every motion inside a region.

    Attributes:
      pt: point–triangle box pairs (``broadphase.Pairs``: point ids ``a``, triangle ids ``b``).
      ee: edge–edge box pairs (edge ids ``a < b``).
      lo, hi: ``(N, 3)`` the region: each particle's box of positions (m).
    """

    pt: bp.Pairs
    ee: bp.Pairs
    lo: jax.Array
    hi: jax.Array

    @property
    def overflow(self) -> jax.Array:
        """``()`` bool, more box pairs (or matches) than slots: some are missing."""
        return self.pt.overflow | self.ee.overflow


@pytree_dataclass
class PairSet:
    """The point–triangle and edge–edge pairs the barrier sees on one motion.

    Attributes:
      pt: ``(P, 4)`` int32 particle ids ``(point, a, b, c)``.
      ee: ``(Q, 4)`` int32 particle ids ``(a0, a1, b0, b1)``.
      pt_on, ee_on: ``(P,)``, ``(Q,)`` bool, the slot holds a pair.
      overflow: ``()`` bool, more pairs than slots (some are missing: the step is not converged).
      source: the :class:`Candidates` they were drawn from (a later motion inside its
        region draws from them again).
    """

    pt: jax.Array
    ee: jax.Array
    pt_on: jax.Array
    ee_on: jax.Array
    overflow: jax.Array
    source: Candidates


def margin(sc):
    """``()`` the margin (m) a search grows its region by: ``REGION`` times ``dhat``."""
    return REGION * sc.dhat


def _region(x, dx, grow):
    """``(lo, hi)``, ``(N, 3)``: each particle's box over the motion from ``x`` to ``x + dx``
    (``None``: at ``x``), grown by ``grow`` (m)."""
    y = x if dx is None else x + dx
    return jnp.minimum(x, y) - grow, jnp.maximum(x, y) + grow


def candidates(sc, x, dx=None, grow=0.0) -> Candidates:
    """The box pairs for every motion inside the region around the motion from ``x`` to
    ``x + dx`` (both ``(N, 3)``; ``None``: at ``x``) grown by ``grow`` (m); where ``grow > 0``,
    around the motion to ``x + (1 + AHEAD) dx``.

    A primitive's box spans its vertices' region boxes, padded by ``dhat / 2``; a pair of
    primitives that share a vertex is left out.  Nothing here is differentiated."""
    if dx is not None:  # a grown region reaches ahead along the motion too
        dx = jax.lax.stop_gradient(dx) * jnp.where(grow > 0, 1.0 + AHEAD, 1.0)
    lo, hi = _region(jax.lax.stop_gradient(x), dx, grow)
    F, E = sc.faces, sc.edges
    pad = 0.5 * sc.dhat
    pts = jnp.arange(x.shape[0], dtype=jnp.int32)[:, None]

    def boxes(ids):  # (the corners per column: XLA:CPU ran a min over the axis of 2-3 as a library call)
        cols = range(ids.shape[1])
        return (functools.reduce(jnp.minimum, (lo[ids[:, k]] for k in cols)) - pad,
                functools.reduce(jnp.maximum, (hi[ids[:, k]] for k in cols)) + pad)

    (lo_p, hi_p), (lo_f, hi_f), (lo_e, hi_e) = boxes(pts), boxes(F), boxes(E)
    pt = bp.overlapping(lo_p, hi_p, lo_f, hi_f, BOX_SLOTS * F.shape[0], pts, F)
    ee = bp.overlapping(lo_e, hi_e, lo_e, hi_e, BOX_SLOTS * E.shape[0], E, E, same=True)
    return Candidates(pt, ee, lo, hi)


def holds(c: Candidates, x, dx) -> jax.Array:
    """``()`` bool, the motion from ``x`` to ``x + dx`` (``(N, 3)``) stays in ``c``'s region
    (and ``c`` missed no pair)."""
    lo, hi = _region(x, dx, 0.0)
    return jnp.all(c.lo <= lo) & jnp.all(hi <= c.hi) & ~c.overflow


def _pt_dist2(x, ids):
    return point_triangle2(x[ids[:, 0]], x[ids[:, 1]], x[ids[:, 2]], x[ids[:, 3]])


def _ee_dist2(x, ids):
    return segment_segment2(x[ids[:, 0]], x[ids[:, 1]], x[ids[:, 2]], x[ids[:, 3]])


def narrow(sc, c: Candidates, x, dx=None) -> PairSet:
    """The pairs of ``c`` whose distance can fall below ``dhat`` on the motion from ``x`` to
    ``x + dx`` (a motion inside ``c``'s region), in ``sc.capacity`` slots each."""
    x = jax.lax.stop_gradient(x)
    dx = None if dx is None else jax.lax.stop_gradient(dx)
    F, E, cap = sc.faces, sc.edges, sc.capacity

    def near(ids, dist2, split):
        d = jnp.sqrt(dist2(x, ids)) - (0.0 if dx is None else ccd.reach(dx[ids], split))
        return ids, d <= sc.dhat

    pt = bp.kept(c.pt, lambda a, b: near(jnp.concatenate([a[:, None], F[b]], axis=1), _pt_dist2, 1), cap, 4)
    ee = bp.kept(c.ee, lambda a, b: near(jnp.concatenate([E[a], E[b]], axis=1), _ee_dist2, 2), cap, 4)
    return PairSet(pt.a, ee.a, pt.on, ee.on, pt.overflow | ee.overflow, c)


def pairs(sc, x, dx=None, grow=0.0) -> PairSet:
    """The pairs closer than ``dhat`` anywhere on the motion from ``x`` to ``x + dx`` (both
    ``(N, 3)``; without ``dx``, at ``x``), drawn from a new search whose region is grown
    by ``grow`` (m).  Nothing here is differentiated."""
    return narrow(sc, candidates(sc, x, dx, grow), x, dx)


def draw(sc, last: PairSet | None, x, dx, grow) -> PairSet:
    """:func:`pairs` on the motion from ``x`` to ``x + dx``, from ``last``'s candidates where
    the motion stays in their region, else (or without ``last``) from a new search grown
    by ``grow`` (m)."""
    if last is None:
        return pairs(sc, x, dx, grow)
    reuse = holds(last.source, x, dx)
    c = jax.lax.cond(reuse, lambda: last.source, lambda: candidates(sc, x, dx, grow))
    return narrow(sc, c, x, dx)


def empty_pairs(capacity: int, faces, edges, x) -> PairSet:
    """A :class:`PairSet` with no pairs and no candidates, marked overflowing (a loop's first
    carry): ``capacity`` slots per kind, for the triangles ``faces (F, 3)`` and their
    ``edges (E, 2)`` over particles like ``x (N, 3)``."""
    z = jnp.zeros((capacity, 4), jnp.int32)
    off = jnp.zeros((capacity,), bool)

    def none(slots):
        zi = jnp.zeros((slots,), jnp.int32)
        return bp.Pairs(zi, zi, jnp.zeros((slots,), bool), jnp.int32(0), jnp.array(True))

    inf = jnp.full(x.shape, jnp.inf, x.dtype)
    c = Candidates(none(BOX_SLOTS * faces.shape[0]), none(BOX_SLOTS * edges.shape[0]), inf, -inf)
    return PairSet(z, z, off, off, jnp.array(True), c)
