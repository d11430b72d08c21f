"""Pairs of overlapping boxes by a sorted uniform grid, at a fixed capacity, under ``jit``.

The cell side is the largest box extent of either set, so a box covers at most 2 x 2 x 2
cells.  The second set's boxes are entered once per covered cell and sorted by a hash of
the cell (packed with the box's id into one word); each box of the first set looks up its
own cells by binary search.  A pair of overlapping boxes is reported from one cell only:
the one holding the corner ``max(lo_a, lo_b)``, which both boxes cover.  The ragged lists
of matches are laid out in ``capacity`` slots by a prefix sum; a run with more matches than
slots says so in ``overflow`` and never drops a pair silently.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from ..._dataclass import pytree_dataclass

#: Matches looked at per slot: a box covers about 4 cells of a cloth's grid, each holding
#: about 10 boxes, so matches outnumber the overlapping pairs about 25 to 1 (two 8x8
#: layers, ``benchmarks/cloth_self_contact.py``).  Two layers closer than a cell share
#: cells, and a motion across a cell's face doubles a box's cells: with 8 the edge-edge
#: search of two 32x32 layers 3 cm apart overflowed on a 5 mm fall (docs/notebook.md,
#: "the 32x32 layers fail"); 12 was enough there up to 2 cm.
RAW_PER_SLOT = 16

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


def _cell_table(hash_b, used_b, keys_a):
    """The second set's cell entries sorted by key, and each query's run of them.

    Args:
      hash_b: ``(B, 8)`` int32 hashes of the cells each box may cover; used_b: ``(B, 8)`` bool.
      keys_a: ``(Q,)`` int32 hashes of the queried cells.

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
    start = jnp.searchsorted(packed, lo, side="left").astype(jnp.int32)
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
    cells_a = first_a[:, None, :] + _CORNERS[None]
    used_a = jnp.all(cells_a <= last_a[:, None, :], axis=-1)
    keys_b, box_b, start, stop = _cell_table(_hash(cells_b), used_b, _hash(cells_a).reshape(-1))
    n = jnp.where(used_a.reshape(-1), stop - start, 0)
    ends = jnp.cumsum(n)
    total = ends[-1]
    raw = RAW_PER_SLOT * capacity  # matches in hashed cells, before the overlap test
    slot = jnp.arange(raw, dtype=jnp.int32)
    # each slot's query, ``#{i: ends[i] <= slot}`` (``searchsorted(ends, slot, "right")``), as a
    # prefix sum of the ends' counts: a scatter and a scan over the slots, where a binary
    # search per slot was most of the search's time (docs/notebook.md, "the broadphase")
    q = jnp.cumsum(jnp.zeros(raw, jnp.int32).at[ends].add(1, mode="drop"))
    q = jnp.minimum(q, ends.shape[0] - 1)
    k = start[q] + slot - (ends[q] - n[q])
    a = q // 8
    b = box_b[jnp.clip(k, 0, keys_b.shape[0] - 1)]
    cell = cells_a.reshape(-1, 3)[q]
    corner = cell_of(jnp.maximum(lo_a[a], lo_b[b]))
    hit = (slot < total) & jnp.all(corner == cell, axis=-1)
    hit = hit & jnp.all((lo_a[a] <= hi_b[b]) & (lo_b[b] <= hi_a[a]), axis=-1)
    if same:
        hit = hit & (a < b)
    if ids_a is not None:
        hit = hit & ~jnp.any(ids_a[a][:, :, None] == ids_b[b][:, None, :], axis=(1, 2))
    return compact(a, b, hit, capacity, total > raw)


def compact(a, b, hit, capacity: int, overflow=False) -> Pairs:
    """The rows of ``a`` and ``b`` (``(R, ...)``; ``b`` may be ``None``) where ``hit (R,)``,
    moved in order to the first of ``capacity`` slots (0 in the rest)."""
    count = jnp.sum(hit, dtype=jnp.int32)
    (idx,) = jnp.nonzero(hit, size=capacity, fill_value=0)
    on = jnp.arange(capacity) < count
    take = lambda r: None if r is None else jnp.where(on.reshape((-1,) + (1,) * (r.ndim - 1)), r[idx], 0)  # noqa: E731
    return Pairs(take(a), take(b), on, count, (count > capacity) | overflow)


#: :func:`overlapping` compiled, for use outside ``jit`` (the boundary's checks).
overlapping_jit = jax.jit(overlapping, static_argnames=("capacity", "same"))
