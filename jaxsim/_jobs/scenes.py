"""Scenes the demo and the report share."""

from __future__ import annotations


def humanoid_targets(skeleton, left="circle", right="heart", size=0.22):
    """``(T, 4, 3)`` targets for ``HUMANOID_EFFECTORS``: the hands trace two of the lab's
    curves (scaled to ``size`` m, in the frontal plane in front of the chest), the feet
    stay at their rest positions."""
    import numpy as np

    from .. import curves, ik

    rest = np.asarray(ik.fk(skeleton).positions)
    a, b = (np.asarray(curves.CURVES[n](), np.float64) for n in (left, right))
    T = min(len(a), len(b))
    out = np.empty((T, 4, 3))
    for k, (c, side) in enumerate(((a[:T], 1.0), (b[:T], -1.0))):
        c = c / np.max(np.abs(c)) * size
        out[:, k] = np.stack([side * (0.3 + c[:, 0]), 1.2 + c[:, 2], np.full(T, 0.35)], axis=-1)
    for k, name in ((2, "l_ankle"), (3, "r_ankle")):
        out[:, k] = rest[skeleton.index(name)]
    return out
