"""A loop over joints that is unrolled in Python for short chains and rolled for long ones.

Per-joint state is held either as a Python list of ``(C, *B)`` arrays (unrolled: every
index is static, so XLA sees one straight-line fusion) or as one stacked ``(J, C, *B)``
array indexed dynamically inside ``lax.fori_loop`` (rolled: compile time independent of
``J``).  The same solver body runs on both.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax

#: Chains with at most this many joints are unrolled (see ``benchmarks/ik_throughput.py``).
UNROLL_MAX_JOINTS = 16


def unrolled(num_joints: int, unroll: bool | None) -> bool:
    return num_joints <= UNROLL_MAX_JOINTS if unroll is None else bool(unroll)


def split(x, unroll: bool):
    """``(J, C, *B)`` -> per-joint container."""
    return [x[i] for i in range(x.shape[0])] if unroll else x


def stack(xs):
    """Per-joint container -> ``(J, C, *B)``."""
    return jnp.stack(xs) if isinstance(xs, list) else xs


def get(xs, i):
    return xs[i]


def put(xs, i, v):
    if isinstance(xs, list):
        out = list(xs)
        out[i] = v
        return out
    return xs.at[i].set(v)


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
