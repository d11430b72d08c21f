"""Built-in rigs, all of them ``Skeleton``s: chains (the lab's arm, straight chains) and a humanoid.

The humanoid: 24 joints, metres, y up, facing +z, an adult about 1.75 m tall in a T-pose
(``l_`` is the character's left, at +x).  Its joints, offsets, rest positions and limits
are tabled in ``docs/ik.md`` ("The built-in humanoid"); ``_rows`` and ``_limit`` below are
the definition.
"""

from __future__ import annotations

import math

import numpy as np

from ..._dtype import check_float_dtype
from ..._validate import check_bool
from .limits import Fixed, Hinge, SwingTwist
from .skeleton import Skeleton, chain_parents

_SPINE = [("pelvis", -1, (0.0, 1.0, 0.0)), ("spine1", 0, (0.0, 0.10, 0.0)), ("spine2", 1, (0.0, 0.12, 0.0)),
          ("spine3", 2, (0.0, 0.12, 0.0)), ("neck", 3, (0.0, 0.14, 0.0)), ("head", 4, (0.0, 0.12, 0.0))]
_ARM = [("clavicle", (0.03, 0.08, 0.0)), ("shoulder", (0.15, 0.02, 0.0)), ("elbow", (0.28, 0.0, 0.0)),
        ("wrist", (0.26, 0.0, 0.0)), ("hand", (0.08, 0.0, 0.0))]
_LEG = [("hip", (0.09, -0.06, 0.0)), ("knee", (0.0, -0.43, 0.0)), ("ankle", (0.0, -0.42, 0.0)),
        ("toe", (0.0, -0.07, 0.13))]

#: Hands and ankles, the usual effectors of a full-body solve.
HUMANOID_EFFECTORS = ("l_hand", "r_hand", "l_ankle", "r_ankle")


def _rows():
    rows = list(_SPINE)
    for part, attach in ((_ARM, 3), (_LEG, 0)):
        for side, sx in (("l", 1.0), ("r", -1.0)):
            parent = attach
            for name, (x, y, z) in part:
                rows.append((f"{side}_{name}", parent, (sx * x, y, z)))
                parent = len(rows) - 1
    return rows


def _deg(x):
    return math.radians(x)


def _limit(name):
    side, part = (name[0], name[2:]) if name[1:2] == "_" else ("", name)
    sign = 1.0 if side == "l" else -1.0
    cones = {"spine1": (25, 20), "spine2": (25, 20), "spine3": (25, 20), "neck": (45, 60), "head": (40, 45),
             "clavicle": (20, 10), "shoulder": (100, 90), "wrist": (70, 80), "hip": (100, 45), "ankle": (40, 20)}
    if part in cones:
        cone, twist = cones[part]
        return SwingTwist(_deg(cone), (-_deg(twist), _deg(twist)))
    if part == "elbow":
        return Hinge((0.0, -sign, 0.0), 0.0, _deg(150))
    if part == "knee":
        return Hinge((1.0, 0.0, 0.0), 0.0, _deg(150))
    if part in ("hand", "toe"):
        return Fixed()
    return None


def humanoid(dtype=None, limits: bool = True) -> Skeleton:
    """The built-in 24-joint humanoid (see the module docstring for names, rest pose and limits).

    Args:
      dtype: float32 or float64; default: float64 under ``jax_enable_x64``, else float32.
      limits: with the joint limits of the module docstring (default), or all joints free.

    Returns:
      ``Skeleton`` with ``names``; ``HUMANOID_EFFECTORS`` lists hands and ankles.
    """
    rows = _rows()
    offsets = np.array([r[2] for r in rows])
    if dtype is not None:
        offsets = offsets.astype(check_float_dtype("humanoid", dtype))
    limits = check_bool("humanoid limits", limits)
    names = tuple(r[0] for r in rows)
    return Skeleton(parents=tuple(r[1] for r in rows), offsets=offsets, names=names,
                    limits=tuple(_limit(n) for n in names) if limits else None)


def Chain(offsets, names=None, limits=None) -> Skeleton:  # noqa: N802 (a constructor, by name)
    """A serial chain of ``J`` ball joints: the ``Skeleton`` with ``parents = (-1, 0, ..., J-2)``.

    Args:
      offsets: ``(J, 3)``.  ``offsets[0]`` is the root joint's world position;
        ``offsets[i]`` for ``i >= 1`` is joint ``i``'s offset from joint ``i-1`` in the
        parent's frame (the lab's ``LocalOffset``), in scene units (metres in the lab).
      names, limits: as for :class:`Skeleton`.

    Raises:
      ValueError: as :class:`Skeleton`, and on offsets that are not ``(J, 3)``.
    """
    shape = np.shape(offsets)
    if len(shape) != 2 or shape[-1] != 3:
        raise ValueError(f"Chain offsets must have shape (J, 3), got {shape}")
    if shape[0] < 2:
        raise ValueError(f"a Chain needs at least 2 joints (one bone), got J={shape[0]}")
    return Skeleton(parents=chain_parents(shape[0]), offsets=offsets, names=names, limits=limits)


def lab_arm() -> Skeleton:
    """The lab's 5-joint arm: root at (0, 1.7, 0), bones 0.8, 0.4, 0.2, 1.2 down -y (reach 2.6)."""
    return Chain(np.array([[0.0, 1.7, 0.0], [0.0, -0.8, 0.0], [0.0, -0.4, 0.0], [0.0, -0.2, 0.0], [0.0, -1.2, 0.0]]))


def straight_chain(lengths, root=(0.0, 0.0, 0.0), direction=(0.0, 0.0, 1.0)) -> Skeleton:
    """A chain whose bones of the given ``lengths`` all point along ``direction`` at rest."""
    lengths = np.asarray(lengths, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    if d.shape != (3,):
        raise ValueError(f"direction must be a 3-vector, got shape {d.shape}")
    n = np.linalg.norm(d)
    if not (np.isfinite(n) and n > 0):
        raise ValueError(f"direction must be a finite non-zero vector, got {direction!r}")
    if lengths.ndim != 1:
        raise ValueError(f"lengths must be a 1D sequence of bone lengths, got shape {lengths.shape}")
    return Chain(np.concatenate([np.asarray(root, np.float64)[None], lengths[:, None] * (d / n)[None]]))
