"""Building a scene's layout once per topology (:func:`layout_of`), and the spring sums
that take one."""

from __future__ import annotations

import hashlib
import weakref
from collections import OrderedDict

import jax
import jax.numpy as jnp
import numpy as np

from ..._dataclass import is_concrete
from .aggregates import aggregate, grid_block
from .particles import ParticleLayout, incidence, index_aggregates
from .planar import PlanarLayout
from .stencil import detect

#: The two layouts (``_layout`` package doc).
Layout = ParticleLayout | PlanarLayout


#: Layouts built so far, by topology (and rest shape, for the voxel aggregates).
_CACHE: OrderedDict = OrderedDict()
_CACHE_SIZE = 64


def _digest(a) -> bytes:
    a = np.ascontiguousarray(a)
    return hashlib.blake2b(a.tobytes() + str((a.dtype, a.shape)).encode(), digest_size=16).digest()


#: The last layouts by the identity of their immutable inputs (``_immutable``), so that a
#: scene stepped one call at a time is not hashed again at every call.
_BY_ID: OrderedDict = OrderedDict()


def layout_of(springs, rest) -> Layout:
    """The layout of a scene with these springs ``(S, 2)`` and rest positions ``(N, 3)``.

    Built from concrete values once per topology (cached); springs only known inside
    ``jit`` give a ``ParticleLayout`` of scatter-adds, a rest shape only known there
    aggregates by particle id.
    """
    N = int(np.shape(rest)[-2])
    if not is_concrete(springs):
        ids, count = index_aggregates(N)
        return ParticleLayout(None, jnp.asarray(ids), count)
    ident = (id(springs), id(rest))
    hit = _BY_ID.get(ident)
    if hit is not None and hit[0]() is springs and hit[1]() is rest:
        return hit[2]
    out = _layout_of(springs, rest, N)
    if _immutable(springs) and _immutable(rest):
        _remember(_BY_ID, ident, (weakref.ref(springs), weakref.ref(rest), out))
    return out


def _immutable(a) -> bool:
    """A ``jax.Array``, or a read-only NumPy array (``Cloth.springs``): safe to know by identity."""
    return isinstance(a, jax.Array) or (isinstance(a, np.ndarray) and not a.flags.writeable and a.base is None)


def _layout_of(springs, rest, N: int) -> Layout:
    s = np.asarray(springs).reshape(-1, 2)
    key = (N, _digest(s))
    st = _CACHE.get(key)
    if st is None:
        st = detect(s, N) or False
        _remember(_CACHE, key, st)
    if st:
        return PlanarLayout(st, grid_block(st.rows, st.cols))
    key_rest = key + (_digest(rest) if is_concrete(rest) else None,)
    out = _CACHE.get(key_rest)
    if out is None:
        ids, count = aggregate(np.asarray(rest)) if is_concrete(rest) else index_aggregates(N)
        with jax.ensure_compile_time_eval():  # concrete arrays even while a ``jit`` traces: they are cached
            out = ParticleLayout(jnp.asarray(incidence(s, N)), jnp.asarray(ids), count)
        _remember(_CACHE, key_rest, out)
    return out


def batch_layout(springs, rest) -> tuple[Layout, bool]:
    """``(layout, batched)`` for a batch of ``B`` scenes: ``springs`` ``(B, S, 2)`` and
    ``rest`` ``(B, N, 3)``, stacked or as sequences of the scenes' own arrays (pass the
    scenes' own, concrete arrays where a ``jit`` around the call would trace the stack).

    One shared layout (``batched`` False) when every scene has the same spring table (the
    first scene's aggregates serve all: any partition gives a valid preconditioner),
    else a ``ParticleLayout`` whose incidence has a leading ``(B,)`` axis, padded to the
    largest degree."""
    springs, rest = list(springs), list(rest)
    if not is_concrete(*springs):
        return layout_of(springs[0], rest[0]), False
    first = layout_of(springs[0], rest[0])
    s = [np.asarray(sb).reshape(-1, 2) for sb in springs]
    if all(np.array_equal(s[0], sb) for sb in s[1:]):
        return first, False
    N = int(np.shape(rest[0])[-2])
    if isinstance(first, PlanarLayout):
        ids, count = aggregate(np.asarray(rest[0])) if is_concrete(rest[0]) else index_aggregates(N)
    else:
        ids, count = first.aggregates, first.num_aggregates
    tables = [incidence(sb, N) for sb in s]
    D = max(t.shape[1] for t in tables)
    inc = np.stack([np.pad(t, ((0, 0), (0, D - t.shape[1]))) for t in tables])
    return ParticleLayout(jnp.asarray(inc), jnp.asarray(np.broadcast_to(ids, (len(s), N))), count), True


def _remember(cache: OrderedDict, key, value) -> None:
    """Put ``value`` in ``cache``, dropping the oldest entries beyond ``_CACHE_SIZE``."""
    cache[key] = value
    while len(cache) > _CACHE_SIZE:
        cache.popitem(last=False)


def spring_diff(cloth, v, layout: Layout | None = None):
    """``v_j - v_i`` for every spring ``(i, j)`` of ``cloth``: ``(N, ...) -> (S, ...)``, by
    ``layout`` (``None``: a gather)."""
    if layout is None:
        return v[cloth.springs[:, 1]] - v[cloth.springs[:, 0]]
    return layout.diff(cloth.springs, v)


def spring_sum(cloth, f, signed: bool = True, layout: Layout | None = None):
    """Per-particle sums of per-spring values ``f (S, ...) -> (N, ...)`` (``ParticleLayout.sum``),
    by ``layout`` (``None``: scatter-adds)."""
    if layout is None:
        layout = ParticleLayout(None, jnp.zeros(cloth.num_particles, jnp.int32), 1)
    return layout.sum(cloth.springs, f, signed)
