"""Target trajectories for IK tracking: the lab's curves, each a ``(T, 3)`` array in the plane y = 0.

Plane coordinates ``(u, v)`` map to world points ``(u, 0, v)`` (scene units, metres in the
lab), so every curve lies in front of the lab arm (root at ``(0, 1.7, 0)``, reach 2.6).
Polygonal shapes are sampled with equal chords (:func:`resample_arclength`).
"""

from __future__ import annotations

import numpy as np

from ._resample import _check_n, _plane, resample_arclength


def from_function(f, t) -> np.ndarray:
    """Targets from any parametric curve ``f(t) -> (x, z)`` or ``-> (T, 3)`` points.

    Args:
      f: callable on the ``(T,)`` parameter array; returns a pair ``(u, v)`` of
        plane coordinates (placed at ``(u, 0, v)``) or an array of shape ``(T, 3)``.
      t: ``(T,)`` parameter values.

    Returns:
      ``(T, 3)`` float64 targets.
    """
    t = np.asarray(t, np.float64)
    out = f(t)
    if isinstance(out, tuple) and len(out) == 2:
        pts = _plane(*out)
    else:
        pts = np.asarray(out, np.float64)
    if pts.shape != t.shape + (3,):
        raise ValueError(f"f must return (u, v) or a {t.shape + (3,)} array, got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("f returned non-finite points")
    return pts


def circle(n: int = 150, radius: float = 0.6) -> np.ndarray:
    """The lab's circle: radius 0.6 about the origin. Returns ``(n, 3)``."""
    t = np.linspace(0.0, 2.0 * np.pi, _check_n(n), endpoint=False)
    return _plane(radius * np.cos(t), radius * np.sin(t))


def _polygon(vertices_uv, n):
    return _plane(*resample_arclength(np.asarray(vertices_uv), _check_n(n), closed=True).T)


def square(n: int = 150, width: float = 0.4) -> np.ndarray:
    """Axis-aligned square of side ``width`` centred on the origin. Returns ``(n, 3)``."""
    h = 0.5 * width
    return _polygon([[-h, -h], [h, -h], [h, h], [-h, h]], n)


def triangle(n: int = 150, radius: float = 0.4) -> np.ndarray:
    """Equilateral triangle inscribed in a circle of ``radius``, apex up. Returns ``(n, 3)``."""
    a = np.pi / 2 + 2 * np.pi * np.arange(3) / 3
    return _polygon(np.stack([radius * np.cos(a), radius * np.sin(a)], -1), n)


def star(n: int = 400, radius: float = 0.4, points: int = 5) -> np.ndarray:
    """Regular star polygon (pentagram outline) with tip ``radius``. Returns ``(n, 3)``.

    The inner vertices sit at ``radius * cos(2π/p) / cos(π/p)`` (0.382 for five points),
    where the edges of the regular star {p/2} cross.
    """
    k = np.arange(2 * points)
    inner = radius * np.cos(2 * np.pi / points) / np.cos(np.pi / points)
    r = np.where(k % 2 == 0, radius, inner)
    a = np.pi / 2 + np.pi * k / points
    return _polygon(np.stack([r * np.cos(a), r * np.sin(a)], -1), n)


def cardioid(n: int = 150, scale: float = 0.5) -> np.ndarray:
    """The lab's heart: ``r = 0.5 (1 - sin θ)`` at ``(r cos θ, 0, r sin θ)``. Returns ``(n, 3)``."""
    t = np.linspace(0.0, 2.0 * np.pi, _check_n(n), endpoint=False)
    r = scale * (1.0 - np.sin(t))
    return _plane(r * np.cos(t), r * np.sin(t))


def heart(n: int = 150, size: float = 0.6) -> np.ndarray:
    """MathWorld's heart curve (the 7th on its Heart Curve page), scaled to ``size``.

    ``x = 16 sin³t``, ``y = 13 cos t - 5 cos 2t - 2 cos 3t - cos 4t``, sampled densely,
    centred and scaled so its larger half-extent is ``size``, then respaced with equal
    chords.  Returns ``(n, 3)``.
    """
    t = np.linspace(0.0, 2.0 * np.pi, 4000, endpoint=False)
    u = 16 * np.sin(t) ** 3
    v = 13 * np.cos(t) - 5 * np.cos(2 * t) - 2 * np.cos(3 * t) - np.cos(4 * t)
    uv = np.stack([u, v], -1)
    uv -= 0.5 * (uv.max(0) + uv.min(0))
    uv *= size / np.max(np.abs(uv))
    return _plane(*resample_arclength(uv, _check_n(n), closed=True).T)


#: The built-in curves by name, each callable with no arguments.
CURVES = {"circle": circle, "square": square, "triangle": triangle, "star": star, "cardioid": cardioid, "heart": heart}
