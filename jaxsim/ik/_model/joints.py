"""A loop over joints that is unrolled in Python for short chains and rolled for long ones.

Per-joint state (vectors or quaternions, see ``_quat``) lives either in a Python list of
component tuples (unrolled: every index is static and a sweep is straight-line
elementwise code) or in one stacked ``(J, C, *B)`` array indexed dynamically inside
``lax.fori_loop`` (rolled: compile time independent of ``J``).  The same solver body
runs on both through ``get``/``put``/``loop``.
"""

from __future__ import annotations

from jax import lax

from ..._geometry import quat as _quat

#: By default the joint loop is unrolled for chains of at most this many joints ...
UNROLL_MAX_JOINTS = 16
#: ... and batches of at least this many targets (``benchmarks/ik_throughput.py``;
#: docs/notebook.md, "Unrolled joint loop").
UNROLL_MIN_BATCH = 256


def unrolled(num_joints: int, unroll: bool | None, batch_size: int = 1) -> bool:
    if unroll is not None:
        return bool(unroll)
    return num_joints <= UNROLL_MAX_JOINTS and batch_size >= UNROLL_MIN_BATCH


def split(x, unroll: bool):
    """``(J, C, *B)`` array -> per-joint container."""
    return [_quat.unstack(x[i]) for i in range(x.shape[0])] if unroll else x


def stack(xs):
    """Per-joint container -> ``(J, C, *B)`` array."""
    if isinstance(xs, list):
        return _quat.stack([_quat.stack(v) for v in xs])
    return xs


def get(xs, i):
    """Joint ``i`` as a component tuple."""
    return xs[i] if isinstance(xs, list) else _quat.unstack(xs[i])


def put(xs, i, v):
    """Replace joint ``i`` with the component tuple ``v``."""
    if isinstance(xs, list):
        out = list(xs)
        out[i] = v
        return out
    return xs.at[i].set(_quat.stack(v).astype(xs.dtype))


def loop(lo: int, hi: int, body, carry, *, unroll: bool, reverse: bool = False):
    """Run ``carry = body(i, carry)`` for ``i`` in ``range(lo, hi)`` (or reversed)."""
    if unroll:
        idx = range(hi - 1, lo - 1, -1) if reverse else range(lo, hi)
        for i in idx:
            carry = body(i, carry)
        return carry
    if reverse:
        return lax.fori_loop(lo, hi, lambda k, c: body(hi - 1 - (k - lo), c), carry)
    return lax.fori_loop(lo, hi, body, carry)
