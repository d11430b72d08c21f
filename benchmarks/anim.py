"""BVH clips: reading and batched FK of the CMU walk tiled to 10,000 frames against pybvh, and foot locking.

``python benchmarks/anim.py [--frames N]``.  The shipped CMU clip (31 joints) is tiled
to ``N`` frames (default 10,000) and written as one BVH file; ``anim.read_bvh`` and
``anim.positions`` (one jitted FK over frames, compile apart from the warm run) are
timed on it, float32 and float64, beside pybvh's reader and ``Bvh.joint_positions``
(NumPy) on the same file, with the largest position difference between the two;
``anim.lock_feet`` on the clip itself, with the toes' slide before and after, and
``anim.retarget`` of the clip onto ``ik.humanoid()`` with its effector errors.
pybvh is a bench-only extra (``pip install -e ".[bench]"``).  Writes
``benchmarks/results/anim.json``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import jax
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import machine, time_call, time_plain, write  # noqa: E402

jax.config.update("jax_enable_x64", True)

from jaxsim import anim, ik  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10_000)
    args = ap.parse_args()
    T = args.frames
    t_start = time.perf_counter()
    clip = anim.read_bvh(anim.CMU_WALK, dtype=np.float64)
    reps = -(-T // clip.num_frames)
    tiled = anim.Motion(skeleton=clip.skeleton, rotations=np.tile(np.asarray(clip.rotations), (reps, 1, 1))[:T],
                        root_positions=np.tile(np.asarray(clip.root_positions), (reps, 1))[:T],
                        frame_time=clip.frame_time, channels=clip.channels, end_sites=clip.end_sites)
    out = {"machine": machine(), "frames": T, "joints": clip.skeleton.num_joints}
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "tiled.bvh")
        anim.write_bvh(path, tiled)
        out["file_mb"] = os.path.getsize(path) / 1e6
        t0 = time.perf_counter()
        ours = {dt: anim.read_bvh(path, dtype=dt) for dt in (np.float64,)}
        out["read_s"] = time.perf_counter() - t0
        ours[np.float32] = anim.read_bvh(path, dtype=np.float32)
        for dt, m in ours.items():
            r = time_call(anim.positions, m)
            name = np.dtype(dt).name
            out[f"positions_{name}"] = {**r, "frames_per_s": T / r["run_s"], "us_per_frame": 1e6 * r["run_s"] / T}
            print(f"anim.positions {name}: compile {r['compile_s']:.2f} s, run {1e3 * r['run_s']:.2f} ms "
                  f"({T / r['run_s']:,.0f} frames/s)")
        print(f"anim.read_bvh: {out['read_s']:.2f} s for {T} frames ({out['file_mb']:.1f} MB)")
        for dt in (np.float64, np.float32):  # foot locking on the clip itself (994 frames)
            walk = anim.cmu_walk(dt)
            feet = ("LeftToe", "RightToe")
            down = anim.foot_contacts(walk, feet)
            r = time_call(lambda: anim.lock_feet(walk, feet, down).rotations)
            locked = anim.lock_feet(walk, feet, down)
            name = np.dtype(dt).name
            out[f"lock_feet_{name}"] = {**r, "frames": walk.num_frames, "us_per_frame": 1e6 * r["run_s"] / walk.num_frames,
                                        "slide_before_m": anim.foot_slide(walk, feet, down).tolist(),
                                        "slide_after_m": anim.foot_slide(locked, feet, down).tolist()}
            print(f"anim.lock_feet {name} on the CMU walk ({walk.num_frames} frames): compile {r['compile_s']:.2f} s, "
                  f"run {1e3 * r['run_s']:.1f} ms; toe slide {1e3 * max(out[f'lock_feet_{name}']['slide_before_m']):.1f} mm "
                  f"-> {1e3 * max(out[f'lock_feet_{name}']['slide_after_m']):.2g} mm")
        walk = anim.cmu_walk(np.float32)  # retargeting the clip onto the humanoid (LM per frame, warm-started)
        mapping = {"l_hand": "LeftWrist", "r_hand": "RightWrist", "l_ankle": "LeftAnkle", "r_ankle": "RightAnkle"}
        H = ik.humanoid(np.float32)
        r = time_call(lambda: anim.retarget(walk, H, mapping).motion.rotations, repeats=2)
        res = anim.retarget(walk, H, mapping)
        err = np.asarray(res.error)
        out["retarget_float32"] = {**r, "frames": walk.num_frames, "ms_per_frame": 1e3 * r["run_s"] / walk.num_frames,
                                   "error_median_m": np.median(err, 0).tolist(),
                                   "error_p95_m": np.percentile(err, 95, 0).tolist(), "error_max_m": err.max(0).tolist(),
                                   "converged": float(np.mean(np.asarray(res.converged))),
                                   "limit_violation": float(np.max(np.asarray(ik.limit_violation(H, res.motion.rotations))))}
        print(f"anim.retarget onto ik.humanoid() float32 ({walk.num_frames} frames): compile {r['compile_s']:.1f} s, "
              f"run {r['run_s']:.2f} s; error p95 {1e3 * np.percentile(err, 95):.1f} mm, "
              f"{100 * out['retarget_float32']['converged']:.1f}% of frames converged")
        try:
            import pybvh
        except ImportError:
            out["pybvh"] = None
            print("pybvh not installed: pip install -e '.[bench]'")
        else:
            t0 = time.perf_counter()
            b = pybvh.read_bvh_file(path)
            read = time.perf_counter() - t0
            fk = time_plain(b.joint_positions)["run_s"]
            P = np.asarray(b.joint_positions())
            diff = float(np.max(np.abs(P - np.asarray(anim.positions(ours[np.float64])))))
            out["pybvh"] = {"version": getattr(pybvh, "__version__", "?"), "read_s": read, "positions_s": fk,
                            "frames_per_s": T / fk, "max_difference": diff}
            print(f"pybvh: read {read:.2f} s, joint_positions {1e3 * fk:.1f} ms ({T / fk:,.0f} frames/s); "
                  f"largest difference from anim.positions {diff:.1e} (file units)")
            out["speedup_positions_float64"] = fk / out["positions_float64"]["run_s"]
    out["wall_s"] = time.perf_counter() - t_start
    write("anim", out)


if __name__ == "__main__":
    main()
