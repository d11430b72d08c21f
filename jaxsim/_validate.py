"""Input checks run at API boundaries, before any tracing; they raise ``ValueError``."""

from __future__ import annotations

from typing import Any

import numpy as np


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
