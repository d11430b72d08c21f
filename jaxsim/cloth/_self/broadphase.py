"""Pairs of overlapping boxes by a sorted uniform grid, at a fixed capacity, under ``jit``.

The cell side is the largest box extent of either set, so a box covers at most 2 x 2 x 2
cells.  The second set's boxes are entered once per covered cell and sorted by a hash of
the cell (packed with the box's id into one word); each box of the first set looks up its
own cells by binary search (within one set, only the boxes after its own: a run is sorted
by box id).  A pair of overlapping boxes is reported from one cell only: the one holding
the corner ``max(lo_a, lo_b)``, which both boxes cover.  The ragged lists of matches are
walked ``CHUNK`` at a time, up to the last match (a loop with a traced trip count: the
work follows the matches, not the budget), and the pairs are laid out in ``capacity``
slots in order; a run with more pairs than slots, or more matches than the budget, says
so in ``overflow`` and never drops a pair silently.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from ..._dataclass import pytree_dataclass

#: Matches looked at per slot, at most (a bound on the search's work, which follows the
#: matches found): a box covers about 4 cells of a cloth's grid, each holding about 10
#: boxes, so matches outnumber the overlapping pairs about 25 to 1 (two 8x8 layers,
#: ``benchmarks/cloth_self_contact.py``; half that within one set).  Two layers closer
#: than a cell share cells, and a motion across a cell's face doubles a box's cells: with 8
#: the edge-edge search of two 32x32 layers 3 cm apart overflowed on a 5 mm fall
#: (docs/notebook.md, "the 32x32 layers fail"); 12 was enough there up to 2 cm.
RAW_PER_SLOT = 16

#: Matches looked at per pass of the search's loop (and pairs per pass of :func:`kept`).
CHUNK = 8192

#: Offsets of the 2 x 2 x 2 cells a box may cover, from its lowest cell.
_CORNERS = jnp.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], jnp.int32)


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


#: Box ids of up to this many bits share one sorted 32-bit word with the cell's hash (its
#: high bits), so the table is a sort of one array, which XLA:CPU sorts several times
#: faster than two arrays sorted together (docs/notebook.md, "the broadphase").
PACKED_ID_BITS = 16


def _once(key, used):
    """``(B, 8)`` bool: ``used``, less the entries whose key an earlier entry of the same box
    has (so a box is found at most once in a run: one pair is never reported twice)."""
    earlier = np.tri(8, k=-1, dtype=bool)  # [i, j]: j < i
    dup = (key[:, :, None] == key[:, None, :]) & used[:, None, :] & earlier
    return used & ~jnp.any(dup, axis=2)


def _cell_table(hash_b, used_b, keys_a, after=None):
    """The second set's cell entries sorted by key, and each query's run of them.

    Args:
      hash_b: ``(B, 8)`` int32 hashes of the cells each box may cover; used_b: ``(B, 8)`` bool.
      keys_a: ``(Q,)`` int32 hashes of the queried cells.
      after: ``(Q,)`` int32 or ``None``: a query's run holds only boxes with ids from this
        one on (the packed table only: its runs are sorted by box id; elsewhere ignored).

    Returns:
      ``(keys, box, start, stop)``: ``(8B,)`` sorted keys and their boxes (unused entries
      last), and ``(Q,)`` int32 the run ``[start, stop)`` of each query's key.  With at most
      ``PACKED_ID_BITS`` bits of box id, a key is the hash's high bits (a bucket: cells whose
      hashes share them share a run, and the overlap test drops the strangers) over the box id.
    """
    B = hash_b.shape[0]
    box = jnp.broadcast_to(jnp.arange(B, dtype=jnp.int32)[:, None], (B, 8))
    bits = max(1, (B - 1).bit_length())
    if bits > PACKED_ID_BITS:
        keys = jnp.where(_once(hash_b, used_b), hash_b, jnp.iinfo(jnp.int32).max).reshape(-1)
        order = jnp.argsort(keys)
        keys, box = keys[order], box.reshape(-1)[order]
        start = jnp.searchsorted(keys, keys_a, side="left").astype(jnp.int32)
        stop = jnp.searchsorted(keys, keys_a, side="right").astype(jnp.int32)
        return keys, box, start, stop
    top = jnp.uint32((1 << (32 - bits)) - 2)  # the last bucket marks unused entries

    def bucket(h):
        return jnp.minimum(lax.bitcast_convert_type(h, jnp.uint32) >> bits, top)

    kb = bucket(hash_b)
    packed = jnp.where(_once(kb, used_b), (kb << bits) | box.astype(jnp.uint32), jnp.uint32(0xFFFFFFFF))
    packed = jnp.sort(packed.reshape(-1))
    lo = bucket(keys_a) << bits
    first = lo if after is None else lo + after.astype(jnp.uint32)  # at most the next bucket's start
    start = jnp.searchsorted(packed, first, side="left").astype(jnp.int32)
    stop = jnp.searchsorted(packed, lo + jnp.uint32(1 << bits), side="left").astype(jnp.int32)
    return packed, (packed & jnp.uint32((1 << bits) - 1)).astype(jnp.int32), start, stop


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
    size = jnp.maximum(ext, jnp.finfo(lo_a.dtype).tiny) * (1 + 1e-6)
    cell_of = lambda x: jnp.floor(x / size).astype(jnp.int32)  # noqa: E731
    # the second set, once per covered cell (at most 8), sorted by the cell's key
    first_b, last_b = cell_of(lo_b), cell_of(hi_b)
    cells_b = first_b[:, None, :] + _CORNERS[None]
    used_b = jnp.all(cells_b <= last_b[:, None, :], axis=-1)
    first_a, last_a = cell_of(lo_a), cell_of(hi_a)
    cells_a = (first_a[:, None, :] + _CORNERS[None]).reshape(-1, 3)
    used_a = jnp.all(cells_a <= jnp.repeat(last_a, 8, axis=0), axis=-1)
    # one set: a query's run starts after its own box (the packed runs are sorted by box id)
    after = jnp.arange(cells_a.shape[0], dtype=jnp.int32) // 8 + 1 if same else None
    keys_b, box_b, start, stop = _cell_table(_hash(cells_b), used_b, _hash(cells_a), after)
    # the queries with matches, in order: their runs' ends rise strictly
    n = jnp.where(used_a, jnp.maximum(stop - start, 0), 0)
    (qs,) = jnp.nonzero(n > 0, size=n.shape[0], fill_value=n.shape[0] - 1)
    qs = qs.astype(jnp.int32)
    nq = jnp.where(jnp.arange(n.shape[0]) < jnp.sum(n > 0), n[qs], 0)
    ends = jnp.cumsum(nq)
    total = ends[-1]
    raw = RAW_PER_SLOT * capacity  # matches looked at, at most
    rows = jnp.arange(CHUNK, dtype=jnp.int32)

    def chunk(i, carry):
        out_a, out_b, count = carry
        s0 = i * CHUNK
        slot = s0 + rows
        # each slot's query ``#{i: ends[i] <= slot}``: the queries before the chunk, and a
        # prefix sum of the chunk's ends (a binary search per slot costs more)
        local = jnp.where(ends >= s0, ends - s0, CHUNK)
        j = jnp.sum(ends < s0) + jnp.cumsum(jnp.zeros(CHUNK, jnp.int32).at[local].add(1, mode="drop"))
        j = jnp.minimum(j, ends.shape[0] - 1)
        q = qs[j]
        k = start[q] + slot - (ends[j] - nq[j])
        a = q // 8
        b = box_b[jnp.clip(k, 0, keys_b.shape[0] - 1)]
        corner = cell_of(jnp.maximum(lo_a[a], lo_b[b]))
        hit = (slot < jnp.minimum(total, raw)) & jnp.all(corner == cells_a[q], axis=-1)
        hit = hit & jnp.all((lo_a[a] <= hi_b[b]) & (lo_b[b] <= hi_a[a]), axis=-1)
        if same:  # (the unpacked table's runs hold every box)
            hit = hit & (a < b)
        if ids_a is not None:
            hit = hit & ~jnp.any(ids_a[a][:, :, None] == ids_b[b][:, None, :], axis=(1, 2))
        (out_a, out_b), count = append((out_a, out_b), (a, b), hit, count)
        return out_a, out_b, count

    z = jnp.zeros(capacity, jnp.int32)
    # only the chunks that hold matches: the work follows the matches, not the budget
    a, b, count = lax.fori_loop(0, (jnp.minimum(total, raw) + CHUNK - 1) // CHUNK, chunk, (z, z, jnp.int32(0)))
    return Pairs(a, b, jnp.arange(capacity) < count, count, (count > capacity) | (total > raw))


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
