"""Foot contacts of a clip: when a foot is down, and how far it slides while down."""

from __future__ import annotations

import numpy as np

from .._validate import check_int, check_real
from ._motion import Motion, positions


def joint_ids(skeleton, joints, what: str = "feet") -> tuple:
    """Joint ids of ``joints`` (names, via ``Skeleton.index``, or indices), at least one."""
    out = []
    for f in joints if isinstance(joints, (tuple, list)) else (joints,):
        if isinstance(f, str):
            out.append(skeleton.index(f))
        elif isinstance(f, (int, np.integer)) and not isinstance(f, bool) and 0 <= int(f) < skeleton.num_joints:
            out.append(int(f))
        else:
            raise ValueError(f"{what} must be joint names or indices in [0, {skeleton.num_joints}), got {f!r}")
    if not out:
        raise ValueError(f"{what} must name at least one joint")
    return tuple(out)


def _joints(motion: Motion, feet) -> tuple:
    return joint_ids(motion.skeleton, feet)


def _check(name, v, positive=True):
    return check_real(name, v, minimum=0.0 if positive else None, strict=positive)


def contact_mask(contacts, shape: tuple) -> np.ndarray:
    """``contacts`` as a bool array of ``shape``: bools, or numbers that are exactly 0 or 1
    (``ValueError`` naming the shape or the first other value: 0.3 is not a contact flag)."""
    c = np.asarray(contacts)
    if c.shape != shape:
        raise ValueError(f"contacts must have shape {shape}, got {c.shape}")
    if c.dtype == bool:
        return c
    if not np.issubdtype(c.dtype, np.number):
        raise ValueError(f"contacts must be bools (or 0 and 1), got {c.dtype!r}")
    other = (c != 0) & (c != 1)
    if other.any():
        raise ValueError(f"contacts must be bools (or 0 and 1), got {c[other][0]!r}")
    return c.astype(bool)


def foot_contacts(motion: Motion, feet, *, height: float = 0.05, speed: float = 0.2, release: float = 1.5,
                  min_frames: int = 3, up: int = 1, floor=None) -> np.ndarray:
    """``(T, F)`` bool: frames where each foot is planted.

    A foot comes down when it is within ``height`` of the floor and moves slower than
    ``speed``; it stays down until it rises above ``release * height`` or moves faster than
    ``release * speed`` (hysteresis, so that noise near a threshold does not flicker).
    Spans shorter than ``min_frames`` are dropped.

    Args:
      motion: the clip.
      feet: joint names or indices (e.g. ``("LeftToe", "RightToe")``).
      height: scene units (metres for :func:`cmu_walk`) above the floor.
      speed: scene units per second, the joint's speed (central differences).
      release: ``> 1``, the hysteresis factor.
      min_frames: the shortest span kept.
      up: the up axis (0, 1 or 2; BVH files are usually y up).
      floor: the floor height; default each foot's 5th percentile of height over the clip
        (its lowest point, robust to a few outlying frames).
    """
    idx = _joints(motion, feet)
    for name, v in (("height", height), ("speed", speed)):
        _check(name, v)
    release = check_real("release", release, minimum=1.0)
    check_int("min_frames", min_frames, 1)
    if floor is not None:
        floor = check_real("floor", floor)
    if isinstance(up, bool) or up not in (0, 1, 2):
        raise ValueError(f"up must be 0, 1 or 2, got {up!r}")
    P = np.asarray(positions(motion), np.float64)[:, idx]  # (T, F, 3)
    T = P.shape[0]
    h = P[..., up] - (np.percentile(P[..., up], 5, axis=0) if floor is None else float(floor))
    v = np.linalg.norm(np.gradient(P, motion.frame_time, axis=0), axis=-1) if T > 1 else np.zeros(h.shape)
    down = np.zeros(h.shape, bool)
    for f in range(len(idx)):
        on = False
        for t in range(T):
            on = (h[t, f] <= release * height and v[t, f] <= release * speed) if on else \
                 (h[t, f] <= height and v[t, f] <= speed)
            down[t, f] = on
        for a, b in contact_spans(down[:, f]):
            if b - a < min_frames:
                down[a:b, f] = False
    return down


def contact_spans(down) -> list:
    """``[(start, stop), ...]`` the runs of True in ``down (T,)`` (``stop`` exclusive)."""
    d = np.concatenate([[False], np.asarray(down, bool), [False]])
    edges = np.flatnonzero(d[1:] != d[:-1])
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def foot_slide(motion: Motion, feet, contacts, *, up: int = 1) -> np.ndarray:
    """``(F,)`` per foot, the largest horizontal distance (scene units) its joint moves from
    where it stands at the start of a contact span, over all its spans (``contacts (T,
    F)`` from :func:`foot_contacts`).  0 where a foot has no span."""
    idx = _joints(motion, feet)
    contacts = contact_mask(contacts, (motion.num_frames, len(idx)))
    P = np.asarray(positions(motion), np.float64)[:, idx]
    flat = [k for k in range(3) if k != up]
    out = np.zeros(len(idx))
    for f in range(len(idx)):
        for a, b in contact_spans(contacts[:, f]):
            d = P[a:b, f][:, flat] - P[a, f][flat]
            out[f] = max(out[f], float(np.sqrt((d * d).sum(-1)).max()))
    return out
