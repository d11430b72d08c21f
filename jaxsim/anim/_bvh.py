"""BVH files in and out (Biovision hierarchy: a joint tree, then one row of channel values
per frame).

Read: ``HIERARCHY``, ``ROOT``/``JOINT name { OFFSET x y z CHANNELS n ... }``, ``End Site
{ OFFSET x y z }``, ``MOTION``, ``Frames: T``, ``Frame Time: s`` and ``T`` rows.  Any
subset of the six channels per joint, in any order (so each of the six Euler orders,
mixed within a file, and position channels on any joint).  A position channel adds to
the joint's ``OFFSET`` (the usual ``ROOT ... OFFSET 0 0 0`` makes it the root's world
position).  Every malformed file raises ``ValueError`` with its line number.
"""

from __future__ import annotations

import os

import jax.numpy as jnp
import numpy as np

from .._dtype import check_float_dtype, default_float
from .._validate import check_real
from ..ik import Skeleton
from ._euler import ORDERS, continuous_euler, euler_to_quat
from ._motion import CHANNELS, Motion

#: Scene units (metres) per length unit of the CMU database's BVH files.
CMU_SCALE = 0.056444
#: The CMU clip 131_01 ("start, walk, stop"; 31 joints, 994 frames at 120 fps) shipped with jaxsim.
CMU_WALK = os.path.join(os.path.dirname(__file__), "data", "cmu_131_01.bvh")

_CANON = {c.lower(): c for c in CHANNELS}


class _Tokens:
    """Whitespace-separated words with their 1-based line numbers."""

    def __init__(self, text: str, path: str):
        self.words, self.lines, self.path = [], [], path
        for n, line in enumerate(text.splitlines(), start=1):
            for w in line.split():
                self.words.append(w)
                self.lines.append(n)
        self.k = 0

    def error(self, msg: str, k: int | None = None) -> ValueError:
        k = self.k if k is None else k
        line = self.lines[min(k, len(self.lines) - 1)] if self.lines else 1
        where = "end of file" if k >= len(self.words) else f"line {line}"
        return ValueError(f"{self.path}: {where}: {msg}")

    def next(self, what: str) -> str:
        if self.k >= len(self.words):
            raise self.error(f"expected {what}, found the end of the file")
        self.k += 1
        return self.words[self.k - 1]

    def expect(self, word: str) -> None:
        w = self.next(repr(word))
        if w != word:
            raise self.error(f"expected {word!r}, found {w!r}", self.k - 1)

    def number(self, what: str) -> float:
        w = self.next(what)
        try:
            v = float(w)
        except ValueError:
            raise self.error(f"{what} must be a number, found {w!r}", self.k - 1) from None
        if not np.isfinite(v):
            raise self.error(f"{what} must be finite, found {w!r}", self.k - 1)
        return v

    def integer(self, what: str) -> int:
        w = self.next(what)
        if not w.isdigit():
            raise self.error(f"{what} must be a non-negative integer, found {w!r}", self.k - 1)
        return int(w)


def _joint(tok: _Tokens, parent: int, joints: list, ends: list) -> None:
    """One ``ROOT``/``JOINT`` block after its keyword: name, ``{``, body, ``}``."""
    name = tok.next("a joint name")
    if name == "{":
        raise tok.error("a joint needs a name before '{'", tok.k - 1)
    tok.expect("{")
    tok.expect("OFFSET")
    offset = [tok.number(f"{name}'s OFFSET") for _ in range(3)]
    channels = ()
    me = len(joints)
    joints.append({"name": name, "parent": parent, "offset": offset, "channels": channels})
    while True:
        kw = tok.next("CHANNELS, JOINT, End Site or '}'")
        if kw == "CHANNELS":
            if channels:
                raise tok.error(f"joint {name!r} has a second CHANNELS line", tok.k - 1)
            at = tok.k
            n = tok.integer(f"{name}'s channel count")
            if n > 6:
                raise tok.error(f"joint {name!r} declares {n} channels; at most 6", at)
            names = []
            for _ in range(n):
                w = tok.next(f"one of {name}'s {n} channel names")
                c = _CANON.get(w.lower())
                if c is None:
                    raise tok.error(f"joint {name!r}: {w!r} is not a channel name (CHANNELS {n} needs {n} of "
                                    f"{', '.join(CHANNELS)})", tok.k - 1)
                if c in names:
                    raise tok.error(f"joint {name!r} lists {c} twice", tok.k - 1)
                names.append(c)
            channels = tuple(names)
            joints[me]["channels"] = channels
        elif kw == "JOINT":
            _joint(tok, me, joints, ends)
        elif kw == "End":
            tok.expect("Site")
            tok.expect("{")
            tok.expect("OFFSET")
            ends.append((me, [tok.number(f"the End Site OFFSET under {name!r}") for _ in range(3)]))
            tok.expect("}")
        elif kw == "}":
            return
        elif kw in ("ROOT", "MOTION"):
            raise tok.error(f"unbalanced braces: {kw} inside joint {name!r} (a '}}' is missing)", tok.k - 1)
        else:
            raise tok.error(f"unknown keyword {kw!r} in joint {name!r}", tok.k - 1)


def parse(text: str, path: str = "<string>"):
    """``(joints, end_sites, frame_time, values (T, C))`` of a BVH text; ``joints`` are
    dicts with ``name``, ``parent``, ``offset`` and ``channels``."""
    tok = _Tokens(text, path)
    tok.expect("HIERARCHY")
    tok.expect("ROOT")
    joints, ends = [], []
    _joint(tok, -1, joints, ends)
    kw = tok.next("MOTION")
    if kw == "}":
        raise tok.error("unbalanced braces: a '}' with no joint open", tok.k - 1)
    if kw == "ROOT":
        raise tok.error("a second ROOT: one skeleton per file", tok.k - 1)
    if kw != "MOTION":
        raise tok.error(f"expected MOTION, found {kw!r}", tok.k - 1)
    tok.expect("Frames:")
    T = tok.integer("the frame count")
    if T < 1:
        raise tok.error(f"the frame count must be >= 1 (a Motion has frames), got {T}", tok.k - 1)
    tok.expect("Frame")
    tok.expect("Time:")
    frame_time = tok.number("the frame time")
    if frame_time <= 0:
        raise tok.error(f"the frame time must be > 0, got {frame_time}", tok.k - 1)
    names = [j["name"] for j in joints]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f"{path}: joint names must be distinct; repeated: {dup}")
    C = sum(len(j["channels"]) for j in joints)
    start = tok.k
    rest = tok.words[start:]
    if len(rest) != T * C:
        got = len(rest) / C if C else len(rest)
        raise tok.error(f"'Frames: {T}' with {C} channels needs {T * C} values, the file has {len(rest)} "
                        f"({got:.4g} frames)", start if rest else None)
    if C and rest:
        line_of = np.asarray(tok.lines[start:])
        per_line = np.bincount(line_of - line_of[0])
        bad = np.flatnonzero((per_line != 0) & (per_line != C))
        if bad.size:
            raise tok.error(f"a frame row has {per_line[bad[0]]} values; each needs {C}",
                            start + int(np.sum(per_line[:bad[0]])))
    try:
        values = np.asarray(rest, np.float64).reshape(T, C)
    except ValueError:
        k = next(i for i, w in enumerate(rest) if not _is_number(w))
        raise tok.error(f"frame values must be numbers, found {rest[k]!r}", start + k) from None
    if not np.all(np.isfinite(values)):
        k = int(np.flatnonzero(~np.isfinite(values.ravel()))[0])
        raise tok.error(f"frame values must be finite, found {rest[k]!r}", start + k)
    return joints, ends, frame_time, values


def _is_number(w: str) -> bool:
    try:
        float(w)
        return True
    except ValueError:
        return False


def read_bvh(path, scale: float = 1.0, dtype=None) -> Motion:
    """Read a BVH file into a :class:`Motion`.

    Args:
      path: the file.
      scale: scene units per file unit (CMU's files: ``0.056444`` for metres).
      dtype: float32 or float64 (float64 only under ``jax_enable_x64``, else float32);
        default jaxsim's.

    Raises:
      ValueError: with the line number, on unbalanced braces, a wrong channel count or an
        unknown channel, a frame count that does not match the values, non-numeric or
        non-finite values, an unknown keyword, or repeated joint names.
    """
    scale = check_real("scale", scale, minimum=0.0, strict=True)
    with open(os.fspath(path), "rb") as f:
        raw = f.read()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw[:e.start].count(b"\n") + 1
        raise ValueError(f"{os.fspath(path)}: line {line}: the file is not UTF-8 text (byte {raw[e.start]:#04x}); "
                         "save it as UTF-8 (joint names are read as UTF-8)") from None
    joints, ends, frame_time, values = parse(text, os.fspath(path))
    dtype = default_float() if dtype is None else check_float_dtype("read_bvh", dtype)  # float64 needs x64
    J, T = len(joints), values.shape[0]
    offsets = scale * np.asarray([j["offset"] for j in joints], np.float64)
    rot = np.zeros((T, J, 4))
    rot[..., 0] = 1.0
    trans = np.zeros((T, J, 3))
    col = 0
    for i, j in enumerate(joints):
        ch = j["channels"]
        v = values[:, col:col + len(ch)]
        col += len(ch)
        r = [k for k, c in enumerate(ch) if c.endswith("rotation")]
        if r:
            rot[:, i] = euler_to_quat(v[:, r], "".join(ch[k][0] for k in r))
        for k, c in enumerate(ch):
            if c.endswith("position"):
                trans[:, i, "XYZ".index(c[0])] = scale * v[:, k]
    root = offsets[0] + trans[:, 0]
    trans[:, 0] = 0.0
    moving = [i for i, j in enumerate(joints) if i > 0 and any(c.endswith("position") for c in j["channels"])]
    sk = Skeleton(parents=tuple(j["parent"] for j in joints), offsets=offsets.astype(dtype),
                  names=tuple(j["name"] for j in joints))
    return Motion(skeleton=sk, rotations=jnp.asarray(rot, dtype), root_positions=jnp.asarray(root, dtype),
                  translations=jnp.asarray(trans, dtype) if moving else None, frame_time=float(frame_time),
                  channels=tuple(j["channels"] for j in joints),
                  end_sites=tuple((int(p), tuple(float(scale * x) for x in o)) for p, o in ends))


def cmu_walk(dtype=None) -> Motion:
    """The shipped CMU clip 131_01 (:data:`CMU_WALK`) in metres, 994 frames at 120 fps, y up:
    a person standing, crouching down and up (frames 360-480), walking about 1 m/s along
    +z (540-720) and stopping."""
    return read_bvh(CMU_WALK, scale=CMU_SCALE, dtype=dtype)


def _fmt(x: float) -> str:
    return f"{x:.6f}"


def write_bvh(path, motion: Motion, order: str | None = None, scale: float = 1.0) -> None:
    """Write ``motion`` as a BVH file.

    Args:
      path: the file.
      motion: a :class:`Motion` (its channels name each joint's; a joint without rotation
        channels whose rotation is not the identity gets ``order``'s, or ``ZXY``).
      order: one of the six Euler orders for every joint's rotation channels, or ``None``
        to keep each joint's own.
      scale: scene units per file unit, as in :func:`read_bvh` (offsets and positions are
        divided by it).

    Euler angles are made continuous across frames (no jumps of 180 or 360 degrees where
    the rotation moves smoothly, ``_euler.continuous_euler``).
    """
    if order is not None and order not in ORDERS:
        raise ValueError(f"order must be one of {ORDERS} or None, got {order!r}")
    scale = check_real("scale", scale, minimum=0.0, strict=True)  # (Motion checked its frame_time)
    sk = motion.skeleton
    J, T = sk.num_joints, motion.num_frames
    names = sk.names or tuple(f"joint{i}" for i in range(J))
    for n in names:  # a name is one word of the file: no white space, no brace
        if not n or any(ch.isspace() for ch in n) or "{" in n or "}" in n:
            raise ValueError(f"joint name {n!r} cannot be written to a BVH file (one word, no white space or braces); "
                             "rename it in the skeleton")
    rot = np.asarray(motion.rotations, np.float64)
    offsets = np.asarray(sk.offsets, np.float64) / scale
    trans = (np.asarray(motion.translations, np.float64).copy() if motion.translations is not None
             else np.zeros((T, J, 3)))
    trans[:, 0] = np.asarray(motion.root_positions, np.float64) - np.asarray(sk.offsets[0], np.float64)
    channels = motion.channels or tuple(() for _ in range(J))
    cols, specs = [], []
    for i in range(J):
        own = channels[i]
        pos = [c for c in own if c.endswith("position")]
        moves = i == 0 or bool(np.any(trans[:, i] != 0))
        if moves and len(pos) < 3:  # the root, or a joint whose offset moves: all three
            pos = pos + [c for c in CHANNELS[:3] if c not in pos]
        rord = "".join(c[0] for c in own if c.endswith("rotation"))
        if order is not None or len(rord) not in (0, 3):
            rord = order or "ZXY"
        if not rord and np.any(np.abs(rot[:, i, 1:]) > 0):
            rord = "ZXY"
        spec = list(pos) + [a + "rotation" for a in rord]
        specs.append(spec)
        if pos:
            t = trans[:, i] / scale
            cols += [t[:, "XYZ".index(c[0])] for c in pos]
        if rord:
            e = continuous_euler(rot[:, i], rord)
            cols += [e[:, k] for k in range(3)]
    kids = [[] for _ in range(J)]
    for i, p in enumerate(sk.parents[1:], start=1):
        kids[p].append(i)
    ends = {}
    for p, o in motion.end_sites:
        ends.setdefault(p, []).append(np.asarray(o, np.float64) / scale)
    out = ["HIERARCHY"]

    def block(i, depth):
        pad = "\t" * depth
        out.append(f"{pad}{'ROOT' if i == 0 else 'JOINT'} {names[i]}")
        out.append(pad + "{")
        out.append(f"{pad}\tOFFSET {' '.join(_fmt(x) for x in offsets[i])}")
        out.append(f"{pad}\tCHANNELS {len(specs[i])} {' '.join(specs[i])}".rstrip())
        for k in kids[i]:
            block(k, depth + 1)
        for o in ends.get(i, []):
            out.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {' '.join(_fmt(x) for x in o)}", f"{pad}\t}}"])
        out.append(pad + "}")

    block(0, 0)
    out += ["MOTION", f"Frames: {T}", f"Frame Time: {float(motion.frame_time)!r}"]
    table = np.stack(cols, axis=1) if cols else np.zeros((T, 0))
    out += [" ".join(_fmt(x) for x in row) for row in table]
    with open(os.fspath(path), "w", encoding="utf-8") as f:
        f.write("\n".join(out) + "\n")
