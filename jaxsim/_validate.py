"""Input checks run at API boundaries, before any tracing; they raise ``ValueError``."""

from __future__ import annotations

from typing import Any

import jax
import numpy as np


def array_like(x: Any):
    """``x`` as an array a jitted entry point takes: arrays (and tracers) as they are, lists
    and scalars through NumPy (a list would be a pytree of scalars)."""
    return x if isinstance(x, (jax.Array, np.ndarray)) else np.asarray(x)


def check_shape(name: str, x: Any, shape: tuple) -> np.ndarray:
    """Return ``np.asarray(x)`` after checking its shape; ``None`` in ``shape`` matches any size."""
    a = np.asarray(x)
    ok = a.ndim == len(shape) and all(s is None or s == d for s, d in zip(shape, a.shape))
    if not ok:
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {want}, got {a.shape}")
    return a


def check_finite(name: str, x: Any) -> np.ndarray:
    """Raise if ``x`` holds NaN or inf."""
    a = np.asarray(x)
    if not np.all(np.isfinite(a)):
        bad = int(np.size(a) - np.count_nonzero(np.isfinite(a)))
        raise ValueError(f"{name} must be finite, but {bad} entries are NaN or inf")
    return a


def check_positive(name: str, x: Any, *, strict: bool = True) -> np.ndarray:
    """Raise unless every entry of ``x`` is > 0 (or >= 0 when ``strict=False``)."""
    a = np.asarray(x)
    bad = a <= 0 if strict else a < 0
    if np.any(bad):
        rel = ">" if strict else ">="
        raise ValueError(f"{name} must be {rel} 0, got min {a.min()!r}")
    return a


def check_int(name: str, x: Any, minimum: int | None = None) -> int:
    """``x`` as a Python int: an ``int`` or numpy integer (not a bool), ``>= minimum``."""
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, np.integer)):
        raise ValueError(f"{name} must be an int, got {x!r} ({type(x).__name__})")
    if minimum is not None and x < minimum:
        raise ValueError(f"{name} must be an int >= {minimum}, got {x!r}")
    return int(x)


def check_bool(name: str, x: Any) -> bool:
    """``x`` as a Python bool; only ``True``/``False`` (or numpy bools) are accepted."""
    if not isinstance(x, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {x!r} ({type(x).__name__})")
    return bool(x)


def check_real(name: str, x: Any, *, minimum: float | None = None, strict: bool = False) -> float:
    """``x`` as a finite Python float: a real number or 0-d real array (not a bool or a string).

    ``minimum``: the smallest allowed value (excluded when ``strict``).
    """
    ok_type = isinstance(x, (int, float, np.integer, np.floating)) or (
        isinstance(x, (np.ndarray, np.generic)) and np.ndim(x) == 0 and np.issubdtype(np.asarray(x).dtype, np.number))
    if hasattr(x, "dtype") and hasattr(x, "shape") and not isinstance(x, (np.ndarray, np.generic)):
        ok_type = np.ndim(x) == 0 and np.issubdtype(np.dtype(x.dtype), np.number)  # a concrete jax scalar
    if isinstance(x, (bool, np.bool_)) or not ok_type:
        raise ValueError(f"{name} must be a real number, got {x!r} ({type(x).__name__})")
    v = float(x)
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite, got {x!r}")
    if minimum is not None and (v <= minimum if strict else v < minimum):
        raise ValueError(f"{name} must be {'>' if strict else '>='} {minimum}, got {x!r}")
    return v


def check_tol(name: str, x: Any) -> None:
    """A finite scalar ``>= 0``; traced values (inside ``jit``) are let through."""
    import jax

    if isinstance(x, jax.core.Tracer):
        return
    if np.ndim(x) != 0 and not isinstance(x, str):
        raise ValueError(f"{name} must be a scalar, got shape {np.shape(x)}")
    check_real(name, x, minimum=0.0)
