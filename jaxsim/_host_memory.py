"""Keeping freed host memory in the process so that compiled programs re-use it.

XLA:CPU gives each call of a compiled program one scratch allocation for all its
temporaries (``compiled.memory_analysis().temp_size_in_bytes``) and frees it on return.
glibc's ``malloc`` serves a block larger than its mmap threshold (at most 32 MiB by
default) with a fresh ``mmap`` and gives it back with ``munmap``, so the next call
touches every page of it again: one minor page fault per 4 KiB.  A converged float64
step of a 128x128 cloth has 56 MB of temporaries, 13,600 faults per call, and spends
over 40% of its time in them (``benchmarks/host_memory.py``).

:func:`retain_host_memory` raises the thresholds from within the process.  Blocks that
XLA's worker threads allocate come from glibc's per-thread arenas, whose heaps cannot
grow past 64 MiB; a larger block is mapped afresh whatever the threshold.  Only the
environment of a new process reaches those (``MALLOC_ARENA_MAX=1`` with the thresholds,
README "Compilation and memory"), since the arenas exist once JAX is imported.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import operator

#: ``mallopt`` parameters (glibc ``malloc.h``).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_INT_MAX = 2**31 - 1

#: The limit last applied by :func:`retain_host_memory` (bytes), ``None`` before.
_retained: int | None = None


@functools.lru_cache(maxsize=1)
def _glibc():
    """The process's C library if it is glibc, else ``None``."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.gnu_get_libc_version  # glibc only
        libc.mallopt
    except (OSError, AttributeError):
        return None
    libc.mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    libc.mallopt.restype = ctypes.c_int
    return libc


def retain_host_memory(limit_bytes: int = 1 << 30) -> bool:
    """Have ``malloc`` keep freed blocks of up to ``limit_bytes`` for re-use (glibc only).

    Raises glibc's mmap and trim thresholds (``mallopt(M_MMAP_THRESHOLD)`` and
    ``M_TRIM_THRESHOLD``) so that a compiled program's scratch memory stays mapped between
    calls instead of being returned to the system and faulted in again: a converged
    float64 step of a 128x128 cloth takes 20 ms instead of 35 ms on a 2-core CPU
    (README, "Compilation and memory").  It covers scratch blocks up to 64 MiB; larger ones
    need the environment settings of the module doc.  Process-wide and not undone; the
    cost is that up to about ``2 * limit_bytes`` of freed memory stays with the process.
    Calling it again only sets the same thresholds.  Does nothing on other C libraries
    (macOS, Windows, musl).

    Args:
      limit_bytes: the largest block kept (bytes), from 1 MiB to 1 GiB.

    Returns:
      True if the thresholds were set, False where the C library is not glibc or it
      refused them.

    Raises:
      TypeError: ``limit_bytes`` is not an integer.
      ValueError: ``limit_bytes`` is outside ``[2**20, 2**30]``.
    """
    try:
        limit = operator.index(limit_bytes)
    except TypeError:
        raise TypeError(f"limit_bytes must be an integer, got {type(limit_bytes).__name__}") from None
    if isinstance(limit_bytes, bool) or not 1 << 20 <= limit <= 1 << 30:
        raise ValueError(f"limit_bytes must be between 2**20 and 2**30, got {limit_bytes!r}")
    libc = _glibc()
    if libc is None:
        return False
    global _retained
    ok = bool(libc.mallopt(_M_MMAP_THRESHOLD, limit)) & bool(libc.mallopt(_M_TRIM_THRESHOLD, min(2 * limit, _INT_MAX)))
    if ok:
        _retained = limit
    return ok


def retained_limit() -> int | None:
    """The limit (bytes) that :func:`retain_host_memory` last applied, ``None`` if none."""
    return _retained
