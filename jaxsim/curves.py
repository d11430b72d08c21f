"""Target trajectories for IK tracking: the lab's curves, each a ``(T, 3)`` array in the plane y = 0."""

from __future__ import annotations

import numpy as np


def _plane(u, v) -> np.ndarray:
    """Map plane coordinates ``(u, v)`` to 3D points ``(u, 0, v)``."""
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    return np.stack([u, np.zeros_like(u), v], axis=-1)


def circle(n: int = 150, radius: float = 0.6) -> np.ndarray:
    """The lab's circle: radius 0.6 about the origin. Returns ``(n, 3)``."""
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return _plane(radius * np.cos(t), radius * np.sin(t))


def cardioid(n: int = 150, scale: float = 0.5) -> np.ndarray:
    """The lab's heart: ``r = 0.5 (1 - sin θ)`` at ``(r cos θ, 0, r sin θ)``. Returns ``(n, 3)``."""
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    r = scale * (1.0 - np.sin(t))
    return _plane(r * np.cos(t), r * np.sin(t))


CURVES = {"circle": circle, "cardioid": cardioid}
