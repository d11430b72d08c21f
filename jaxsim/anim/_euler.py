"""Euler angles in BVH's convention, to and from unit quaternions (NumPy, float64).

A BVH joint lists its rotation channels in the order they compose: ``Zrotation
Xrotation Yrotation`` is ``R = Rz(a) Rx(b) Ry(c)`` acting on column vectors (intrinsic
rotations about the moving axes, in the listed order), angles in degrees.  Quaternions
are ``(w, x, y, z)`` as everywhere in jaxsim.
"""

from __future__ import annotations

import numpy as np

from .._geometry import quat as _quat

AXES = "XYZ"
#: The six Tait-Bryan orders (every axis once), as BVH files use them.
ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")


def axis_quaternions(axis: str, radians) -> np.ndarray:
    """``(..., 4)`` rotations by ``radians (...)`` about ``axis`` (one of ``"XYZ"``)."""
    a = 0.5 * np.asarray(radians, np.float64)
    q = np.zeros(a.shape + (4,))
    q[..., 0] = np.cos(a)
    q[..., 1 + AXES.index(axis)] = np.sin(a)
    return q


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a b`` of ``(..., 4)`` NumPy quaternions (``_quat.mul``, kept in
    NumPy float64 whatever the x64 setting)."""
    return np.stack(_quat.mul(np.moveaxis(a, -1, 0), np.moveaxis(b, -1, 0)), axis=-1)


def euler_to_quat(degrees, order: str) -> np.ndarray:
    """``(..., 4)`` unit quaternions of Euler angles ``degrees (..., len(order))``.

    ``order`` names the axes in composition order (``"ZXY"``: ``Rz Rx Ry``); any number
    of axes, so a joint with one or two rotation channels works too.
    """
    if not (isinstance(order, str) and order and all(c in AXES for c in order)):
        raise ValueError(f"order must name rotation axes from 'XYZ' in composition order (e.g. 'ZXY'), got {order!r}")
    d = np.radians(np.asarray(degrees, np.float64))
    if d.ndim < 1 or d.shape[-1] != len(order):
        raise ValueError(f"degrees must have shape (..., {len(order)}), one angle per axis of {order!r}, got "
                         f"{d.shape}")
    q = np.zeros(d.shape[:-1] + (4,))
    q[..., 0] = 1.0
    for k, axis in enumerate(order):
        q = qmul(q, axis_quaternions(axis, d[..., k]))
    return q


def _matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def quat_to_euler(q, order: str) -> np.ndarray:
    """``(..., 3)`` Euler angles in degrees of unit quaternions ``q (..., 4)``, ``order`` one
    of :data:`ORDERS`: the principal solution, middle angle in ``[-90, 90]``.

    With ``R = R_i(a) R_j(b) R_k(c)`` and ``s = +1`` for a cyclic order (``XYZ``, ``YZX``,
    ``ZXY``), ``-1`` otherwise: ``sin b = s R[i, k]``, ``a = atan2(-s R[j, k], R[k, k])``,
    ``c = atan2(-s R[i, j], R[i, i])``.  At gimbal lock (``cos b`` below 1e-7) ``c = 0`` and
    ``a`` is the rotation left, ``R R_j(b)^T = R_i(a)``.
    """
    if order not in ORDERS:
        raise ValueError(f"order must be one of {ORDERS}, got {order!r}")
    i, j, k = (AXES.index(c) for c in order)
    s = 1.0 if (j - i) % 3 == 1 else -1.0
    M = _matrix(np.asarray(q, np.float64))
    cb = np.hypot(M[..., i, i], M[..., i, j])  # |cos b|, accurate where arcsin(sin b) is not
    b = np.arctan2(s * M[..., i, k], cb)
    a = np.arctan2(-s * M[..., j, k], M[..., k, k])
    c = np.arctan2(-s * M[..., i, j], M[..., i, i])
    lock = cb < 1e-7
    if np.any(lock):
        Rj = _matrix(axis_quaternions(order[1], b[lock]))
        A = M[lock] @ np.swapaxes(Rj, -1, -2)  # = R_i(a) when c = 0
        u, v = (i + 1) % 3, (i + 2) % 3
        a[lock], c[lock] = np.arctan2(A[..., v, u], A[..., u, u]), 0.0
    return np.degrees(np.stack([a, b, c], axis=-1))


def continuous_euler(q, order: str) -> np.ndarray:
    """``(T, 3)`` Euler angles in degrees of ``q (T, 4)`` that change least frame to frame.

    Each frame picks, of the two Tait-Bryan solutions ``(a, b, c)`` and ``(a + 180,
    180 - b, c + 180)`` with each angle shifted by a multiple of 360 to the nearest of the
    previous frame's, the one closest to the previous frame: no jump of 180 or 360
    degrees where the rotation itself moves smoothly; at gimbal lock, where only the sum
    or difference of the outer angles is fixed, the last frame's third angle is kept.
    The first frame is principal.
    """
    q = np.asarray(q, np.float64)
    e = quat_to_euler(q, order)
    out = np.empty_like(e)
    if len(e):
        out[0] = e[0]
    for t in range(1, len(e)):
        a, b, c = e[t]
        cands = [np.array([a, b, c]), np.array([a + 180.0, 180.0 - b, c + 180.0])]
        if abs(abs(b) - 90.0) < 1e-5:  # gimbal lock: only a -/+ c is fixed; keep the last c
            cp = out[t - 1][2]
            for sgn in (1.0, -1.0):
                cand = np.array([a - sgn * cp, b, cp])
                if np.abs(np.abs(np.sum(euler_to_quat(cand, order) * q[t])) - 1.0) < 1e-12:
                    cands.append(cand)
        best = None
        for cand in cands:
            cand = cand - 360.0 * np.round((cand - out[t - 1]) / 360.0)
            d = np.sum((cand - out[t - 1]) ** 2)
            if best is None or d < best[0]:
                best = (d, cand)
        out[t] = best[1]
    return out
