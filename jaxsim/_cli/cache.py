"""JAX's persistent compilation cache for the command line: opt-in.

Every new shape (batch size, grid size, number of steps) compiles anew, 1 to 3 s for a
solver; the persistent cache keeps compiled programs on disk so a second run of a command
reuses them.  It is off unless ``$JAX_COMPILATION_CACHE_DIR`` names a folder: with jaxlib
0.10.2 on CPU, serialising an executable for the cache (and reading one back) crashed the
process intermittently (a segmentation fault or an abort inside JAX's cache code, about
once per few thousand programs in our test runs), and a crash costs more than a compile.
"""

from __future__ import annotations

import os


def cache_dir() -> str | None:
    """``$JAX_COMPILATION_CACHE_DIR``, or ``None`` (no cache)."""
    return os.environ.get("JAX_COMPILATION_CACHE_DIR") or None


def enable_compilation_cache() -> str | None:
    """With ``$JAX_COMPILATION_CACHE_DIR`` set, turn the cache on for programs that took
    0.5 s or more to compile and return the folder; otherwise (or if the folder cannot be
    created) leave it off and return ``None``."""
    import jax

    d = cache_dir()
    if d is None:
        return None
    try:
        os.makedirs(d, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", d)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    return d
