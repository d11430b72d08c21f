"""Floating dtype policy: float32 by default, float64 when ``jax_enable_x64`` is on."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


def default_float() -> np.dtype:
    """The default floating dtype under the current x64 setting."""
    return jnp.zeros((), dtype=float).dtype


def as_float(x: Any, dtype: Any = None) -> jax.Array:
    """``x`` as a floating jax array: ``dtype`` if given, else its own float dtype, else the default."""
    if dtype is None:
        dt = getattr(x, "dtype", None)
        if dt is not None and jnp.issubdtype(dt, jnp.floating):
            dtype = jax.dtypes.canonicalize_dtype(dt)
        else:
            dtype = default_float()
    return jnp.asarray(x, dtype=dtype)


def eps(dtype: Any) -> float:
    """Machine epsilon of ``dtype``."""
    return float(jnp.finfo(dtype).eps)


def tiny(dtype: Any) -> float:
    """A safe threshold below which a length is treated as zero (about sqrt of the smallest normal)."""
    return float(np.sqrt(jnp.finfo(dtype).tiny)) * 16.0


#: The floating dtypes a scene or chain may have.
SUPPORTED = (np.dtype(np.float32), np.dtype(np.float64))


def check_float_dtype(what: str, dtype: Any) -> np.dtype:
    """``dtype`` as a numpy dtype, if it is float32 or float64; else a ``ValueError``.

    Half precision (float16, bfloat16) is rejected: with 3 significant digits a step's
    motion, a spring's stretch or a bone's length is lost to rounding.
    """
    try:
        d = np.dtype(dtype)
    except TypeError:
        raise ValueError(f"{what} dtype must be float32 or float64, got {dtype!r}") from None
    if d not in SUPPORTED:
        extra = " (half precision cannot resolve the motion of a step)" if np.issubdtype(d, np.floating) or "bfloat16" in str(d) else ""
        raise ValueError(f"{what} dtype must be float32 or float64, got {d}{extra}")
    return np.dtype(jax.dtypes.canonicalize_dtype(d))


def check_array_dtype(what: str, dtype: Any) -> None:
    """Input arrays may be float32/float64 (kept) or integers (made the default float)."""
    d = np.dtype(dtype)
    if np.issubdtype(d, np.floating) or d.name == "bfloat16":
        check_float_dtype(what, d)
    elif not np.issubdtype(d, np.integer):
        raise ValueError(f"{what} must hold real numbers, got dtype {d}")
