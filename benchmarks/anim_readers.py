"""Do other BVH readers read what ``anim.write_bvh`` writes?

``python benchmarks/anim_readers.py``.  The shipped CMU walk is written in each of the
six Euler orders, and its foot-locked version (rotations that never came from a file)
in its own orders; each file is read by pybvh (``Bvh.joint_positions``, every frame) and
by bvhio (``readAsHierarchy``, then ``loadPose`` and ``PositionWorld``, every 10th frame),
and their joint positions are compared with ``anim.positions`` of the clip before writing
(file units).  pybvh and bvhio are bench-only extras (``pip install -e ".[bench]"``).
Writes ``benchmarks/results/anim_readers.json``.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from importlib.metadata import version

import jax
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import machine, write  # noqa: E402

jax.config.update("jax_enable_x64", True)

from jaxsim import anim  # noqa: E402

ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")


def main() -> int:
    try:
        import bvhio
        import pybvh
    except ImportError as e:
        print(f"{e.name} is not installed (a bench extra): pip install -e '.[bench]'; nothing measured",
              file=sys.stderr)
        return 1

    t_start = time.perf_counter()
    clip = anim.read_bvh(anim.CMU_WALK, dtype=np.float64)
    locked = anim.lock_feet(clip, ("LeftToe", "RightToe"))
    out = {"machine": machine(), "frames": clip.num_frames, "joints": clip.skeleton.num_joints,
           "pybvh": version("pybvh"), "bvhio": version("bvhio"), "files": {}}
    cases = [(f"cmu_{o}", clip, o) for o in ORDERS] + [("cmu_locked_own_orders", locked, None)]
    with tempfile.TemporaryDirectory() as d:
        for name, motion, order in cases:
            path = os.path.join(d, name + ".bvh")
            anim.write_bvh(path, motion, order=order)
            want = np.asarray(anim.positions(motion))
            got = np.asarray(pybvh.read_bvh_file(path).joint_positions())
            d_pybvh = float(np.max(np.abs(got - want)))
            root = bvhio.readAsHierarchy(path)
            joints = [j for j, _, _ in root.layout()]
            assert [j.Name for j in joints] == list(motion.skeleton.names), "bvhio's joint order"
            frames = range(0, motion.num_frames, 10)
            d_bvhio = 0.0
            for t in frames:
                root.loadPose(t)
                p = np.array([[j.PositionWorld.x, j.PositionWorld.y, j.PositionWorld.z] for j in joints])
                d_bvhio = max(d_bvhio, float(np.max(np.abs(p - want[t]))))
            out["files"][name] = {"order": order or "own", "pybvh_max_difference": d_pybvh,
                                  "bvhio_max_difference": d_bvhio, "bvhio_frames": len(frames)}
            print(f"{name}: largest difference from anim.positions, pybvh {d_pybvh:.1e}, "
                  f"bvhio {d_bvhio:.1e} (file units, 0.0564 m each)")
    out["wall_s"] = time.perf_counter() - t_start
    write("anim_readers", out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
