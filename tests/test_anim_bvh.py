"""``jaxsim.anim``: BVH in and out, against a NumPy BVH reader written here with rotation
matrices; mixed orders, round trips, continuity, every malformed file, gradients."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxsim import anim

CLIP, CMU_SCALE = anim.CMU_WALK, anim.CMU_SCALE


def _axis_matrix(axis, deg):
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    i = "XYZ".index(axis)
    u, v = (i + 1) % 3, (i + 2) % 3
    R = np.zeros(np.shape(a) + (3, 3))
    R[..., i, i] = 1.0
    R[..., u, u], R[..., v, v], R[..., u, v], R[..., v, u] = c, c, -s, s
    return R


def numpy_bvh_positions(text, scale=1.0):
    """``(T, J, 3)`` joint positions of a BVH text by matrices: the reference."""
    words = text.split()
    k = words.index("MOTION")
    joints, stack, i = [], [], 0
    while i < k:
        w = words[i]
        if w in ("ROOT", "JOINT"):
            joints.append({"parent": stack[-1] if stack else -1})
            stack.append(len(joints) - 1)
            i += 2
        elif w == "End":
            stack.append(None)
            i += 2
        elif w == "}":
            stack.pop()
            i += 1
        elif w == "OFFSET" and stack[-1] is not None:
            joints[stack[-1]]["offset"] = scale * np.array(words[i + 1:i + 4], float)
            i += 4
        elif w == "CHANNELS":
            n = int(words[i + 1])
            joints[stack[-1]]["channels"] = words[i + 2:i + 2 + n]
            i += 2 + n
        else:
            i += 1
    T = int(words[k + 2])
    vals = np.array(words[k + 6:], float).reshape(T, -1)
    P, R, col = [], [], 0
    for j in joints:
        ch = j.get("channels", [])
        rot = np.broadcast_to(np.eye(3), (T, 3, 3))
        off = np.broadcast_to(j["offset"], (T, 3)).copy()
        for c in ch:
            if c.endswith("rotation"):
                rot = rot @ _axis_matrix(c[0], vals[:, col])
            else:
                off[:, "XYZ".index(c[0])] += scale * vals[:, col]
            col += 1
        if j["parent"] < 0:
            P.append(off)
            R.append(rot)
        else:
            Rp = R[j["parent"]]
            P.append(P[j["parent"]] + np.einsum("tij,tj->ti", Rp, off))
            R.append(Rp @ rot)
    return np.stack(P, axis=1)


@pytest.fixture(scope="module")
def clip():
    with open(CLIP) as f:
        text = f.read()
    m = anim.cmu_walk(np.float64)
    assert m.skeleton.names == anim.read_bvh(CLIP, dtype=np.float64).skeleton.names
    return text, m


def test_the_shared_clip_against_numpy(clip):
    text, m = clip
    assert m.num_frames == 994 and m.skeleton.num_joints == 31 and abs(m.frame_time - 0.0083333) < 1e-12
    assert m.skeleton.names[:3] == ("Hips", "LHipJoint", "LeftHip") and len(m.end_sites) == 7
    assert {m.rotation_order(i) for i in range(31)} == {"ZYX", "ZXY"}  # the file mixes two orders
    assert m.skeleton.zero_length_joints() == (1, 6, 11, 14, 17, 21, 23, 24, 28, 30)
    P = np.asarray(anim.positions(m))
    np.testing.assert_allclose(P, numpy_bvh_positions(text, CMU_SCALE), atol=1e-10)
    assert 1.2 < P[0, :, 1].max() - P[0, :, 1].min() < 1.6  # metres: ankle to head of a standing person
    m32 = anim.read_bvh(CLIP, scale=CMU_SCALE, dtype=np.float32)
    assert m32.rotations.dtype == np.float32
    np.testing.assert_allclose(np.asarray(anim.positions(m32)), P, atol=2e-5)


MIXED = """HIERARCHY
ROOT base
{
  OFFSET 0.5 1.0 -0.25
  CHANNELS 6 Zrotation Xposition Yrotation Yposition Xrotation Zposition
  JOINT a
  {
    OFFSET 0 2 0
    CHANNELS 3 Xrotation Zrotation Yrotation
    JOINT b
    {
      OFFSET 1 0 0
      CHANNELS 5 Yposition Yrotation Xrotation Zrotation Xposition
      End Site
      {
        OFFSET 0 0 1
      }
    }
  }
  JOINT c
  {
    OFFSET 0 0 0
    CHANNELS 1 Yrotation
    JOINT d
    {
      OFFSET 0 -1 0
      CHANNELS 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.04
"""


def _mixed_text(rows=None):
    rng = np.random.default_rng(3)
    vals = rng.uniform(-170, 170, (3, 15)) if rows is None else rows
    return MIXED + "\n".join(" ".join(f"{v:.5f}" for v in r) for r in vals) + "\n"


def test_mixed_orders_and_position_channels(tmp_path):
    text = _mixed_text()
    path = tmp_path / "mixed.bvh"
    path.write_text(text)
    m = anim.read_bvh(path, scale=0.5, dtype=np.float64)
    assert [m.rotation_order(i) for i in range(5)] == ["ZYX", "XZY", "YXZ", "Y", ""]
    assert m.translations is not None and m.end_sites == ((2, (0.0, 0.0, 0.5)),)
    np.testing.assert_allclose(np.asarray(anim.positions(m)), numpy_bvh_positions(text, 0.5), atol=1e-12)
    for order in (None,) + anim.ORDERS:  # written back in its own orders or in each of the six
        anim.write_bvh(tmp_path / "out.bvh", m, order=order, scale=0.5)
        back = anim.read_bvh(tmp_path / "out.bvh", scale=0.5, dtype=np.float64)
        assert back.skeleton.names == m.skeleton.names and back.skeleton.parents == m.skeleton.parents
        np.testing.assert_allclose(np.asarray(anim.positions(back)), np.asarray(anim.positions(m)), atol=1e-6)
        assert back.end_sites == m.end_sites


def test_the_shared_clip_round_trips(clip, tmp_path):
    _, m = clip
    P = np.asarray(anim.positions(m))
    for order in (None, "XYZ", "YZX"):
        anim.write_bvh(tmp_path / "clip.bvh", m, order=order, scale=CMU_SCALE)
        back = anim.read_bvh(tmp_path / "clip.bvh", scale=CMU_SCALE, dtype=np.float64)
        assert back.channels[0][:3] == ("Xposition", "Yposition", "Zposition")
        np.testing.assert_allclose(np.asarray(anim.positions(back)), P, atol=1e-6)


@pytest.mark.parametrize("order", anim.ORDERS)
def test_euler_round_trip_and_continuity(order):
    rng = np.random.default_rng(7)
    e = rng.uniform(-180, 180, (400, 3))
    e[:100, 1] = 90.0 * np.sign(rng.normal(size=100))  # gimbal lock
    q = anim.euler_to_quat(e, order)
    q2 = anim.euler_to_quat(anim.quat_to_euler(q, order), order)
    assert np.max(np.minimum(np.abs(q - q2).max(-1), np.abs(q + q2).max(-1))) < 1e-8
    # a smooth turn through the wrap at 180 degrees and through gimbal lock: no jumps
    t = np.linspace(0, 1, 300)[:, None]
    smooth = anim.euler_to_quat(np.hstack([170 + 40 * t, -80 + 170 * t, 100 * np.sin(6 * t)]), order)
    written = anim.continuous_euler(smooth, order)
    assert np.abs(np.diff(written, axis=0)).max() < 10.0
    back = anim.euler_to_quat(written, order)
    assert np.max(np.minimum(np.abs(back - smooth).max(-1), np.abs(back + smooth).max(-1))) < 1e-8


GOOD_ROW = " ".join(["1.00000"] * 15)
BAD_ROW = " ".join(["1.00000"] * 14)


@pytest.mark.parametrize("edit, match", [
    (lambda s: s.replace("JOINT d\n    {", "JOINT d\n    {\n    {"), "line 26: expected 'OFFSET', found '{'"),
    (lambda s: s.replace("      }\n    }\n  }\n  JOINT c", "      }\n    }\n  JOINT c"), "MOTION inside joint 'base'"),
    (lambda s: s.replace("}\nMOTION", "}\n}\nMOTION"), "line 31: unbalanced braces"),
    (lambda s: s.replace("CHANNELS 3 Xrotation", "CHANNELS 4 Xrotation"), "line 10: joint 'a': 'JOINT' is not a channel"),
    (lambda s: s.replace("CHANNELS 1 Yrotation", "CHANNELS 1 Wrotation"), "line 23: joint 'c': 'Wrotation'"),
    (lambda s: s.replace("CHANNELS 1 Yrotation", "CHANNELS 2 Yrotation Yrotation"), "lists Yrotation twice"),
    (lambda s: s.replace("CHANNELS 1 Yrotation", "CHANNELS x Yrotation"), "line 23: c's channel count"),
    (lambda s: s.replace("Frames: 3", "Frames: 4"), "'Frames: 4' with 15 channels needs 60 values, the file has 45"),
    (lambda s: s.replace("Frames: 3", "Frames: 2"), "needs 30 values, the file has 45"),
    (lambda s: s.replace(GOOD_ROW, BAD_ROW + " abc", 1), "line 34: frame values must be numbers, found 'abc'"),
    (lambda s: s.replace(GOOD_ROW, BAD_ROW + " nan", 1), "line 34: frame values must be finite"),
    (lambda s: s.replace("OFFSET 0 2 0", "OFFSET 0 two 0"), "line 8: a's OFFSET must be a number"),
    (lambda s: s.replace("    CHANNELS 0\n", "    CHANNELS 0\n    LIMITS 0 1\n"), "line 28: unknown keyword 'LIMITS' in joint 'd'"),
    (lambda s: s.replace("JOINT c", "JOINT a"), "joint names must be distinct; repeated: \\['a'\\]"),
    (lambda s: s.replace("Frame Time: 0.04", "Frame Time: 0"), "frame time must be > 0"),
    (lambda s: s.replace("HIERARCHY", "HIERARCHIE"), "line 1: expected 'HIERARCHY'"),
    (lambda s: s.replace(GOOD_ROW + "\n" + GOOD_ROW, GOOD_ROW + " 1.0\n" + BAD_ROW, 1), "line 34: a frame row has 16 values"),
    (lambda s: s.split("MOTION")[0], "end of file: expected MOTION"),
])
def test_malformed_files_name_their_line(tmp_path, edit, match):
    text = edit(_mixed_text(np.ones((3, 15))))
    path = tmp_path / "bad.bvh"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        anim.read_bvh(path)


def test_bad_arguments():
    with pytest.raises(ValueError, match="scale"):
        anim.read_bvh(CLIP, scale=0.0)
    with pytest.raises(ValueError, match="float32 or float64"):
        anim.read_bvh(CLIP, dtype=np.float16)
    m = anim.read_bvh(CLIP, dtype=np.float32)
    for kw, match in ((dict(rotations=m.rotations[:, :5]), r"rotations must have shape \(T, 31, 4\)"),
                      (dict(root_positions=m.root_positions[:10]), r"root_positions must have shape \(994, 3\)"),
                      (dict(translations=np.zeros((994, 31, 2))), "translations must have shape"),
                      (dict(frame_time=0.0), "frame_time"), (dict(channels=((),)), "channels must name")):
        with pytest.raises(ValueError, match=match):
            dataclasses.replace(m, **kw)
    with pytest.raises(TypeError, match="Skeleton"):
        dataclasses.replace(m, skeleton="hips")
    with pytest.raises(ValueError, match="order"):
        anim.quat_to_euler(np.array([1.0, 0, 0, 0]), "XXY")


def test_positions_jit_vmap_and_gradients(tmp_path):
    path = tmp_path / "mixed.bvh"
    path.write_text(_mixed_text())
    m = anim.read_bvh(path, dtype=np.float64)
    P = anim.positions(m)
    np.testing.assert_allclose(np.asarray(jax.jit(anim.positions)(m)), np.asarray(P), atol=1e-14)
    flipped = m.rotations.at[..., 1:].multiply(-1.0)  # the inverse rotations: a second clip
    Pv = jax.vmap(lambda r: anim.positions(dataclasses.replace(m, rotations=r)))(jnp.stack([m.rotations, flipped]))
    np.testing.assert_allclose(np.asarray(Pv[0]), np.asarray(P), atol=1e-14)
    np.testing.assert_allclose(np.asarray(Pv[1]), np.asarray(anim.positions(dataclasses.replace(m, rotations=flipped))),
                               atol=1e-14)

    def end(offsets, rotations, root):
        sk = m.skeleton.__class__(parents=m.skeleton.parents, offsets=offsets, names=m.skeleton.names)
        mm = anim.Motion(skeleton=sk, rotations=rotations, root_positions=root, translations=m.translations,
                         frame_time=m.frame_time, channels=m.channels)
        return jnp.sum(anim.positions(mm)[:, -1] ** 2)

    check_grads(end, (m.skeleton.offsets, m.rotations, m.root_positions), order=1, modes=("rev",))


@pytest.mark.parametrize("frame_time", [1e-8, 1.5e-7, 1 / 120, 0.0333, 1 / 3])
def test_the_frame_time_round_trips_exactly(tmp_path, frame_time):
    """``Frame Time`` is written with enough digits for an exact float round trip (seven
    decimals wrote 1e-8 as 0.0000000, which the reader refuses, and 1.5e-7 as 2e-7)."""
    m = dataclasses.replace(anim.read_bvh(CLIP, dtype=np.float32), frame_time=frame_time)
    path = tmp_path / "ft.bvh"
    anim.write_bvh(path, m)
    assert anim.read_bvh(path).frame_time == frame_time


def test_unwritable_motions_are_refused_before_writing(tmp_path):
    """A joint name the file cannot hold, an End Site on a joint that does not exist and an
    unknown channel name are refused (they were written, or dropped, into files that do not
    read back)."""
    m = anim.read_bvh(CLIP, dtype=np.float32)
    names = ("Left Hip",) + m.skeleton.names[1:]
    spaced = dataclasses.replace(m, skeleton=dataclasses.replace(m.skeleton, names=names))
    with pytest.raises(ValueError, match="joint name 'Left Hip' cannot be written"):
        anim.write_bvh(tmp_path / "a.bvh", spaced)
    assert not (tmp_path / "a.bvh").exists()
    with pytest.raises(ValueError, match=r"end_sites\[0\] must be \(joint id in \[0, 31\)"):
        dataclasses.replace(m, end_sites=((31, (0.0, 1.0, 0.0)),))
    with pytest.raises(ValueError, match="'Wrotation', not a channel name"):
        dataclasses.replace(m, channels=(("Xposition", "Wrotation"),) + m.channels[1:])


def _tiny_bvh(frames="Frames: 2", rows="0 0 0 0 0 0 0 0 0\n0 0 0 0 0 0 0 10 0\n", name="Knee"):
    return ("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition Zposition Zrotation "
            f"Xrotation Yrotation\n  JOINT {name}\n  {{\n    OFFSET 0 -1 0\n    CHANNELS 3 Zrotation Xrotation "
            f"Yrotation\n    End Site\n    {{\n      OFFSET 0 -1 0\n    }}\n  }}\n}}\nMOTION\n{frames}\n"
            f"Frame Time: 0.0333\n{rows}")


def test_obscure_reader_errors_name_the_file_and_line(tmp_path):
    p = tmp_path / "x.bvh"
    p.write_text(_tiny_bvh(frames="Frames: 0", rows=""))
    with pytest.raises(ValueError, match=r"x.bvh: line 17: the frame count must be >= 1"):
        anim.read_bvh(p)
    p.write_text(_tiny_bvh(frames="Frames: two"))
    with pytest.raises(ValueError, match=r"line 17: the frame count must be a non-negative integer, found 'two'"):
        anim.read_bvh(p)
    p.write_bytes(_tiny_bvh(name="Kn\xe9e").encode("latin-1"))
    with pytest.raises(ValueError, match=r"x.bvh: line 6: the file is not UTF-8 text \(byte 0xe9\)"):
        anim.read_bvh(p)
    p.write_text(_tiny_bvh().replace("OFFSET 0 -1 0\n    }", "OFFSET a -1 0\n    }"))
    with pytest.raises(ValueError, match=r"line 12: the End Site OFFSET under 'Knee' must be a number"):
        anim.read_bvh(p)
    p.write_text(_tiny_bvh().replace("CHANNELS 3 Zrotation Xrotation Yrotation",
                                     "CHANNELS 3 Zrotation Xrotation Yrotation\n CHANNELS 1 Xrotation"))
    with pytest.raises(ValueError, match="joint 'Knee' has a second CHANNELS line"):
        anim.read_bvh(p)
    p.write_text(_tiny_bvh())
    assert anim.read_bvh(p, scale=np.float32(2.0)).skeleton.offsets[1, 1] == -2.0  # a numpy scalar is a number
    for bad in (True, "2", 0.0, np.inf):
        with pytest.raises(ValueError, match="scale"):
            anim.read_bvh(p, scale=bad)


def test_motion_values_are_checked_not_reinterpreted():
    m = anim.read_bvh(CLIP, dtype=np.float32)
    with pytest.raises(ValueError, match="frame_time .* must be a real number, got 'a'"):
        dataclasses.replace(m, frame_time="a")
    with pytest.raises(ValueError, match=r"zero quaternion \(frame 3, joint 2\)"):
        dataclasses.replace(m, rotations=m.rotations.at[3, 2].set(0.0))
    with pytest.raises(ValueError, match="at least 1 frame"):
        dataclasses.replace(m, rotations=m.rotations[:0], root_positions=m.root_positions[:0])


def test_euler_and_resample_arguments_name_the_value():
    with pytest.raises(ValueError, match="order must name rotation axes from 'XYZ'.*got 'W'"):
        anim.euler_to_quat([1.0, 2.0, 3.0], "W")
    with pytest.raises(ValueError, match=r"degrees must have shape \(\.\.\., 3\).*got \(2,\)"):
        anim.euler_to_quat([1.0, 2.0], "XYZ")
    m = anim.read_bvh(CLIP, dtype=np.float32)
    with pytest.raises(ValueError, match="frame_time=1e-12 s .* frames \\(at most 600,000\\)"):
        anim.resample(m, 1e-12)  # tried to allocate terabytes
