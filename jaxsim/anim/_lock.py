"""Foot locking: during each contact span a foot stays at one point, by two-bone IK of its
leg in every frame at once."""

from __future__ import annotations

import dataclasses
import functools
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .._dataclass import pytree_dataclass
from .._geometry import quat as _quat
from .._validate import check_int
from ..ik._solvers.two_bone import two_bone
from ._contacts import _joints, contact_mask, contact_spans, foot_contacts
from ._motion import Motion, _fk, _offsets


def _legs(motion: Motion, feet) -> tuple:
    """Per foot ``(foot, ankle, knee, hip)``: the foot joint and the three joints above it."""
    par = motion.skeleton.parents
    zero_length = motion.skeleton.zero_length_joints()
    legs = []
    for e in _joints(motion, feet):
        a = par[e]
        k = par[a] if a > 0 else -1
        h = par[k] if k > 0 else -1
        if h < 0:
            raise ValueError(f"foot joint {e} needs three joints above it (ankle, knee, hip), the root excluded")
        zero = [j for j in (e, a, k) if j in zero_length]
        if zero:
            raise ValueError(f"foot joint {e}'s leg has zero-length bones at joints {zero}; name the toe, below a "
                             "hip, knee and ankle with bones")
        if motion.translations is not None and np.any(np.asarray(motion.translations)[:, [e, a, k]] != 0):
            raise ValueError(f"foot joint {e}'s leg has position channels: its bone lengths move")
        legs.append((e, a, k, h))
    return tuple(legs)


def _weights(down: np.ndarray, blend: int):
    """``(w (T,), seg (T,))``: 1 inside a span, a smoothstep ramp over ``blend`` frames on
    each side, 0 elsewhere; ``seg`` the span each frame blends toward (its index, or the
    number of spans, at most ``T``, for frames that blend toward none)."""
    T = len(down)
    spans = contact_spans(down)
    w, seg = np.zeros(T), np.full(T, len(spans))
    for k, (a, b) in enumerate(spans):
        for t in range(max(0, a - blend), min(T, b + blend)):
            d = (a - t) if t < a else (t - b + 1) if t >= b else 0
            x = 1.0 - d / (blend + 1)
            x = x * x * (3 - 2 * x)
            if x > w[t]:
                w[t], seg[t] = x, k
    return w, seg


#: The share of a leg's length the hip may be from the ankle before the root is lowered.
REACH = 0.9995
#: A knee this close to its hip-ankle line (a share of the leg's length) counts as straight.
STRAIGHT = 1e-4
#: A foot counts as held where it ends within this share of its leg's length of its target.
HELD = 1e-3


@pytree_dataclass
class LockInfo:
    """How well :func:`lock_feet` held each foot.

    Attributes:
      held: ``(T, F)`` bool, the foot ends within ``HELD`` (0.1%) of its leg's length of
        its target; True on frames it was not asked to move (no span, no blend).
      miss: ``(T, F)`` scene units, the foot's distance from its target (0 where not asked).
      max_miss: ``(F,)`` the largest ``miss`` of each foot.
      drop: ``(T,)`` how far the root was lowered (scene units).
    """

    held: jax.Array
    miss: jax.Array
    max_miss: jax.Array
    drop: jax.Array


@functools.partial(jax.jit, static_argnames=("parents", "legs", "up"))
def _lock(parents, legs, offsets, root, rotations, weights, segs, up):
    P, G = _fk(parents, offsets, root, rotations)
    bone = lambda j: offsets[..., j, :]  # noqa: E731  (3,) or (T, 3)
    length = lambda j: jnp.linalg.norm(offsets.reshape(-1, len(parents), 3)[0, j])  # noqa: E731
    q = lambda j: _quat.unstack(G[:, j], -1)  # noqa: E731
    v = lambda x: _quat.unstack(x, -1)  # noqa: E731
    T = P.shape[0]  # span ids are below T + 1: one program for any number of spans
    ankles, targets, drop = [], [], jnp.zeros((T,), P.dtype)
    for f, (e, a, k, h) in enumerate(legs):
        pe = P[:, e]
        inside = weights[:, f] >= 1.0
        sums = jax.ops.segment_sum(jnp.where(inside[:, None], pe, 0.0), segs[:, f], num_segments=T + 1)
        cnt = jax.ops.segment_sum(inside.astype(pe.dtype), segs[:, f], num_segments=T + 1)
        lock = (sums / jnp.maximum(cnt, 1.0)[:, None])[segs[:, f]]  # each span's mean position
        tgt = pe + weights[:, f, None] * (lock - pe)
        targets.append(tgt)
        ankle = _quat.stack(_quat.sub(v(tgt), _quat.rotate(q(a), v(bone(e)))), -1)
        ankles.append(ankle)
        # the root's drop along -up that brings the hip within REACH of the leg's length of the ankle
        r = REACH * (length(k) + length(a))
        d = P[:, h] - ankle
        s = d[:, up]
        q2 = jnp.sum(d * d, -1) - s * s
        need = jnp.where((jnp.sum(d * d, -1) > r * r) & (weights[:, f] > 0), s - jnp.sqrt(jnp.maximum(r * r - q2, 0.0)), 0.0)
        drop = jnp.maximum(drop, jnp.maximum(need, 0.0))
    P = P.at[..., up].add(-drop[:, None])  # the whole body moves down: world rotations unchanged
    R = rotations
    for f, (e, a, k, h) in enumerate(legs):
        ph, pk, pa = v(P[:, h]), v(P[:, k]), v(P[:, a])
        # the knee bends away from the hip-ankle line, as it is bent; a leg straight to within
        # STRAIGHT of its length bends toward its toe (knees bend forward, toes point forward)
        line = _quat.normalize(_quat.sub(pa, ph), (0.0, 0.0, 0.0))
        hk = _quat.sub(pk, ph)
        bend = _quat.sub(hk, _quat.scale(_quat.dot(hk, line), line))  # the knee off the hip-ankle line
        d_toe = _quat.sub(v(P[:, e]), pa)
        toe = _quat.normalize(d_toe, tuple(jnp.zeros_like(x) for x in d_toe))
        straight = _quat.safe_norm(bend) <= STRAIGHT * (length(k) + length(a))
        pole = _quat.add(pk, _quat.where(straight, _quat.scale(length(k) + length(a), toe), bend))
        lengths = jnp.stack([length(k), length(a)])
        tb = two_bone(P[:, h], ankles[f], _quat.stack(pole, -1), lengths)
        dh = _quat.from_two_vectors(_quat.sub(pk, ph), _quat.sub(v(tb.mid), ph))
        gh = _quat.mul(dh, q(h))
        dk = _quat.from_two_vectors(_quat.rotate(dh, _quat.sub(pa, pk)), _quat.sub(v(tb.end), v(tb.mid)))
        gk = _quat.mul(dk, _quat.mul(dh, q(k)))
        lh = gh if parents[h] < 0 else _quat.mul(_quat.conj(q(parents[h])), gh)
        lk = _quat.mul(_quat.conj(gh), gk)
        la = _quat.mul(_quat.conj(gk), q(a))
        R = R.at[:, h].set(_quat.stack(lh, -1)).at[:, k].set(_quat.stack(lk, -1)).at[:, a].set(_quat.stack(la, -1))
    P2, _ = _fk(parents, offsets, root.at[:, up].add(-drop), R)
    miss = jnp.stack([jnp.where(weights[:, f] > 0, jnp.linalg.norm(P2[:, e] - tg, axis=-1), 0.0)
                      for f, ((e, _, _, _), tg) in enumerate(zip(legs, targets))], axis=1)
    reach = jnp.stack([length(k) + length(a) for (_, a, k, _) in legs])
    return R, drop, miss, reach


def lock_feet(motion: Motion, feet, contacts=None, *, blend: int = 6, up: int = 1, info: bool = False):
    """``motion`` with each foot held at one point during each of its contact spans.

    Per span, the foot joint's target is its mean position over the span; over ``blend``
    frames before and after, the target eases (smoothstep) between the input and the
    lock.  In every frame at once, the leg above the foot (hip, knee, ankle: the three
    joints above it) is solved by two-bone IK (``ik.two_bone``) toward the ankle point that
    puts the foot on its target with the ankle's world rotation unchanged, bending the
    knee toward its input side; the hip's and knee's rotations turn by the shortest arcs
    from the input bones to the solved ones.  Bone lengths are kept (only rotations
    change).  Where a target is beyond the leg's reach, the root is lowered along ``-up``
    until the hip is within 0.9995 of the leg's length of the ankle point (the largest
    drop over the feet); frames away from every span are unchanged.

    Args:
      motion: the clip.
      feet: foot joints (names or indices), each below an ankle, knee and hip: the toes
        of a BVH rig (``("LeftToe", "RightToe")`` on :func:`cmu_walk`).
      contacts: ``(T, F)`` bool, or ``None`` for :func:`foot_contacts` with its defaults.
      blend: frames of easing on each side of a span (``>= 0``).
      up: the up axis (0, 1 or 2).
      info: also return a :class:`LockInfo` (which frames held each foot, by how much
        they missed).

    Returns:
      A :class:`Motion` with new local rotations of the hips, knees and ankles, and the
      root lowered where a leg could not reach; with ``info``, ``(motion, LockInfo)``.
      A lock point beyond the leg's reach (the root moving far during one contact) cannot
      be held: without ``info`` that warns, naming the foot and its largest miss.
    """
    legs = _legs(motion, feet)
    if isinstance(up, bool) or up not in (0, 1, 2):
        raise ValueError(f"up must be 0, 1 or 2, got {up!r}")
    blend = check_int("blend", blend, 0)
    if contacts is None:
        contacts = foot_contacts(motion, feet)
    contacts = contact_mask(contacts, (motion.num_frames, len(legs)))
    ws, segs = zip(*(_weights(contacts[:, f], blend) for f in range(len(legs))))
    dtype = motion.rotations.dtype
    R, drop, miss, reach = _lock(motion.skeleton.parents, legs, _offsets(motion), motion.root_positions,
                                 motion.rotations, jnp.asarray(np.stack(ws, 1), dtype), jnp.asarray(np.stack(segs, 1)),
                                 up)
    out = dataclasses.replace(motion, rotations=R, root_positions=motion.root_positions.at[:, up].add(-drop))
    held = miss <= HELD * reach
    report = LockInfo(held=held, miss=miss, max_miss=jnp.max(miss, axis=0), drop=drop)
    if info:
        return out, report
    if not bool(jnp.all(held)):
        f = int(jnp.argmax(jnp.max(miss / reach, axis=0)))
        bad = np.flatnonzero(~np.asarray(held[:, f]))
        warnings.warn(f"lock_feet could not hold foot joint {legs[f][0]} in {int((~np.asarray(held)).sum())} frame(s) "
                      f"(first: {bad[:5].tolist()}): its lock point is beyond the leg's reach, missed by up to "
                      f"{float(report.max_miss[f]):.3g}; lock_feet(..., info=True) returns which frames held",
                      stacklevel=2)
    return out
