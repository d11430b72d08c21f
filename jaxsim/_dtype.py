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
