"""Pairs of overlapping boxes by a hashed uniform grid, at a fixed capacity, under ``jit``.

The cell side is the largest box extent of either set (times ``1 + SLACK``).  Each box of
the second set is entered once, in its *home* cell (the one holding its lowest corner
``lo``); the table is one sort of the boxes by their home's bucket (a hash of the cell)
and the buckets' runs.  Two boxes that overlap have homes at most one cell apart on each
axis, so a box of the first set looks in at most the 3 x 3 x 3 cells around its home, and
only in those its own box reaches (``cell(hi)``); within one set, only in its home and the
13 neighbours of one half-space (each unordered pair is met once; MD's half-shell cell
list).  A match counts only where the entry's home is the cell looked in (strangers in a
bucket are dropped), so a pair is reported once, with no duplicate test.  The ragged lists
of matches are walked ``CHUNK`` at a time, up to the last match (a loop with a traced trip
count: the work follows the matches, not the budget), and the pairs are laid out in
``capacity`` slots in order; a run with more pairs than slots, or more matches than the
budget, says so in ``overflow`` and never drops a pair silently.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from ..._dataclass import pytree_dataclass

#: Matches looked at per slot, at most (a bound on the search's work, which follows the
#: matches found).  Two 32x32 layers on a sphere (``benchmarks/cloth_self_contact.py``,
#: float64, frame 14; 12 slots a primitive): 70 k point-triangle and 208 k edge-edge
#: matches at rest for 2,071 and 8,815 box pairs, and 351 k and 736 k over a grown
#: quarter-frame motion (``_self.pairs``: 12,089 and 39,064 pairs), against budgets of
#: 738 k and 1.13 M.  A search over budget says so and is retried without the margin.
RAW_PER_SLOT = 16

#: Matches looked at per pass of the search's loop (and pairs per pass of :func:`kept`).
CHUNK = 8192

#: The cell side is the largest extent times ``1 + SLACK``: two overlapping boxes' homes
#: stay within one cell of each other on each axis through the rounding of ``x / side``
#: (up to about ``SLACK / eps`` cells from the origin).
SLACK = 1e-3

#: A table of at most this many bits of ``bucket * B + box`` is sorted as one ``uint32``
#: word, which XLA:CPU sorts several times faster than keys with ids carried
#: (docs/notebook.md, "the broadphase"); larger tables use a stable ``argsort``.
PACKED_BITS = 32

#: Home offsets a box of the first set looks in: all 27, and within one set the home
#: itself (first) and the 13 whose first nonzero component is positive.
_ALL = np.array([[i, j, k] for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], np.int32)
_HALF = np.array([d for d in _ALL if not d.any()] + [d for d in _ALL if d.any() and d[np.flatnonzero(d)[0]] > 0],
                 np.int32)


@pytree_dataclass
class Pairs:
    """Candidate pairs ``(a, b)`` in fixed slots.

    Attributes:
      a: ``(P,)`` int32 ids into the first set (0 in unused slots).
      b: ``(P,)`` int32 ids into the second set (0 in unused slots), or ``None``.
      on: ``(P,)`` bool, the slot holds a pair.
      count: ``()`` int32 pairs found (more than ``P``, or a lower bound, when it overflowed).
      overflow: ``()`` bool, more pairs than slots: some are missing.
    """

    a: jax.Array
    b: jax.Array
    on: jax.Array
    count: jax.Array
    overflow: jax.Array


def _hash(cell):
    """``(..., 3)`` int32 cells to an int32 key (wrapping; collisions are filtered later)."""
    c = cell.astype(jnp.uint32)
    h = c[..., 0] * jnp.uint32(73856093) ^ c[..., 1] * jnp.uint32(19349663) ^ c[..., 2] * jnp.uint32(83492791)
    return lax.bitcast_convert_type(h, jnp.int32)


def _bucket(cell, bits: int):
    """``(...,)`` uint32 bucket in ``[0, 2^bits)`` of ``(..., 3)`` int32 cells: the high bits of
    the hash times Knuth's multiplicative constant."""
    h = lax.bitcast_convert_type(_hash(cell), jnp.uint32) * jnp.uint32(2654435761)
    return h >> (32 - bits)


def _table(home):
    """The boxes sorted by their home cell's bucket, and each bucket's run.

    Args:
      home: ``(B, 3)`` int32 home cells.

    Returns:
      ``(box (B,) int32, start (T,) int32, count (T,) int32, bits)``: box ids in bucket order
      (by id within a bucket), and bucket ``k``'s run ``box[start[k] : start[k] + count[k]]``,
      for ``T = 2^bits >= 2 B`` buckets.
    """
    B = home.shape[0]
    bits = max(1, (2 * B - 1).bit_length())
    kb = _bucket(home, bits)
    if (B << bits) - 1 < 2 ** PACKED_BITS:  # bucket * B + box fits one word
        box = (jnp.sort(kb * jnp.uint32(B) + jnp.arange(B, dtype=jnp.uint32)) % jnp.uint32(B)).astype(jnp.int32)
    else:
        box = jnp.argsort(kb, stable=True).astype(jnp.int32)
    count = jnp.zeros(1 << bits, jnp.int32).at[kb].add(1)
    return box, jnp.cumsum(count) - count, count, bits


def overlapping(lo_a, hi_a, lo_b, hi_b, capacity: int, ids_a=None, ids_b=None, same: bool = False) -> Pairs:
    """Every pair of boxes ``a`` of the first set and ``b`` of the second that overlap.

    Args:
      lo_a, hi_a: ``(A, 3)`` corners of the first set's boxes (m).
      lo_b, hi_b: ``(B, 3)`` the second set's.
      capacity: static number of slots ``P``.
      ids_a, ids_b: ``(A, k)`` and ``(B, l)`` int32 vertex ids of the boxes' primitives: a pair
        that shares a vertex is left out before it takes a slot (``None``: keep all).
      same: the two sets are one set: each unordered pair once (``a < b``).

    Returns:
      :class:`Pairs`, with the found pairs first.
    """
    ext = jnp.maximum(jnp.max(hi_a - lo_a), jnp.max(hi_b - lo_b))
    size = jnp.maximum(ext, jnp.finfo(lo_a.dtype).tiny) * (1 + SLACK)
    cell_of = lambda x: jnp.floor(x / size).astype(jnp.int32)  # noqa: E731
    home_b = cell_of(lo_b)
    box_b, run_start, run_count, bits = _table(home_b)
    # each box of the first set looks in the homes around its own that its box reaches
    offs = jnp.asarray(_HALF if same else _ALL)
    home_a = cell_of(lo_a)
    reach = cell_of(hi_a) - home_a
    cells = home_a[:, None, :] + offs[None]  # (A, K, 3)
    used = jnp.all(offs[None] <= reach[:, None, :], axis=-1)
    K = offs.shape[0]
    cells = cells.reshape(-1, 3)
    bk = _bucket(cells, bits)
    n = jnp.where(used.reshape(-1), run_count[bk], 0)
    first = run_start[bk]
    # the queries with matches, in order: their runs' ends rise strictly
    Q = n.shape[0]
    (qs,) = jnp.nonzero(n > 0, size=Q, fill_value=Q - 1)
    qs = qs.astype(jnp.int32)
    nq = jnp.where(jnp.arange(Q) < jnp.sum(n > 0), n[qs], 0)
    ends = jnp.cumsum(nq)
    total = ends[-1]
    raw = RAW_PER_SLOT * capacity  # matches looked at, at most
    rows = jnp.arange(CHUNK, dtype=jnp.int32)
    # each chunk's first query, ``#{i: ends[i] <= start}``; a chunk's slots belong to at most
    # ``CHUNK`` queries from there (each holds a match)
    heads = jnp.searchsorted(ends, jnp.arange(-(-raw // CHUNK), dtype=ends.dtype) * CHUNK, side="right")
    ends_p = jnp.concatenate([ends, jnp.full(CHUNK, jnp.iinfo(ends.dtype).max, ends.dtype)])

    def chunk(i, carry):
        out_a, out_b, count = carry
        s0 = i * CHUNK
        slot = s0 + rows
        j0 = heads[i].astype(jnp.int32)
        # each slot's query ``j0 + #{k: ends[j0 + k] <= slot}``: a prefix sum over the window
        local = jnp.minimum(lax.dynamic_slice_in_dim(ends_p, j0, CHUNK) - s0, CHUNK)
        j = jnp.minimum(j0 + jnp.cumsum(jnp.zeros(CHUNK, jnp.int32).at[local].add(1, mode="drop")), Q - 1)
        q = qs[j]
        b = box_b[jnp.clip(first[q] + slot - (ends[j] - nq[j]), 0, box_b.shape[0] - 1)]
        a = q // K
        hit = (slot < jnp.minimum(total, raw)) & jnp.all(home_b[b] == cells[q], axis=-1)
        hit = hit & jnp.all((lo_a[a] <= hi_b[b]) & (lo_b[b] <= hi_a[a]), axis=-1)
        if same:  # the home's own run holds the box itself and each pair in it twice
            hit = hit & ((q % K != 0) | (a < b))
            a, b = jnp.minimum(a, b), jnp.maximum(a, b)
        if ids_a is not None:
            hit = hit & ~jnp.any(ids_a[a][:, :, None] == ids_b[b][:, None, :], axis=(1, 2))
        (out_a, out_b), count = append((out_a, out_b), (a, b), hit, count)
        return out_a, out_b, count

    z = jnp.zeros(capacity, jnp.int32)
    # only the chunks that hold matches: the work follows the matches, not the budget
    a, b, count = lax.fori_loop(0, (jnp.minimum(total, raw) + CHUNK - 1) // CHUNK, chunk, (z, z, jnp.int32(0)))
    wide = jnp.any(reach > 1)  # a box wider than a cell (rounding): its homes are not all looked in
    return Pairs(a, b, jnp.arange(capacity) < count, count, (count > capacity) | (total > raw) | wide)


def append(outs, rows, hit, count):
    """``(outs, count)``: the ``rows`` where ``hit (C,)`` written in order after the first
    ``count`` rows of each of ``outs`` (those past the end dropped), and the new count."""
    at = jnp.where(hit, count + jnp.cumsum(hit, dtype=jnp.int32) - 1, outs[0].shape[0])
    return tuple(o.at[at].set(r, mode="drop") for o, r in zip(outs, rows)), count + jnp.sum(hit, dtype=jnp.int32)


def kept(found: Pairs, test, capacity: int, width: int) -> Pairs:
    """The pairs of ``found`` that pass ``test``, in order, in ``capacity`` slots.

    Args:
      found: pairs in order (found first), as :func:`overlapping` returns them.
      test: ``(a (C,), b (C,)) -> (rows (C, width) int32, keep (C,) bool)`` on ``CHUNK``
        slots at a time.
      capacity: static slots of the result.
      width: static columns of ``rows``.

    Returns:
      :class:`Pairs` whose ``a`` holds the ``(capacity, width)`` rows (``b`` is ``None``),
      overflowing where ``found`` did or the kept ones outnumber the slots.  Only the
      chunks up to the last found pair are tested.
    """
    P = found.on.shape[0]
    size = -(-P // CHUNK) * CHUNK
    fa, fb, fon = (jnp.pad(v, (0, size - P)) for v in (found.a, found.b, found.on))

    def chunk(i, carry):
        out, count = carry
        a, b, on = (lax.dynamic_slice_in_dim(v, i * CHUNK, CHUNK) for v in (fa, fb, fon))
        r, keep = test(a, b)
        (out,), count = append((out,), (r,), on & keep, count)
        return out, count

    used = jnp.minimum(found.count, P)
    out, count = lax.fori_loop(0, (used + CHUNK - 1) // CHUNK, chunk,
                               (jnp.zeros((capacity, width), jnp.int32), jnp.int32(0)))
    return Pairs(out, None, jnp.arange(capacity) < count, count, (count > capacity) | found.overflow)


#: :func:`overlapping` compiled, for use outside ``jit`` (the boundary's checks).
overlapping_jit = jax.jit(overlapping, static_argnames=("capacity", "same"))
