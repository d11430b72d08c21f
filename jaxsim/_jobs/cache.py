"""JAX's persistent compilation cache for the command line.

Every new shape (batch size, grid size, number of steps) compiles anew, 1 to 3 s for a
solver; the cache keeps compiled programs on disk so a second run of a command reuses
them.  Library users turn it on the same way (README, "Compilation").
"""

from __future__ import annotations

import os


def cache_dir() -> str:
    """``$JAX_COMPILATION_CACHE_DIR``, else ``~/.cache/jaxsim/jax``."""
    return os.environ.get("JAX_COMPILATION_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "jaxsim", "jax")


def enable_compilation_cache() -> str | None:
    """Turn the cache on (programs that took 0.5 s or more to compile); returns the folder,
    or ``None`` if it cannot be created or ``$JAXSIM_NO_CACHE`` is set (``--no-cache``):
    the commands then run without it."""
    import jax

    if os.environ.get("JAXSIM_NO_CACHE"):
        return None
    d = cache_dir()
    try:
        os.makedirs(d, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", d)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    return d
