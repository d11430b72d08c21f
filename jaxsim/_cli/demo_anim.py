"""Demo section: the CMU walk with its feet locked, and retargeted onto the humanoid
(``anim_walk.gif``)."""

from __future__ import annotations

import os
import time

MAPPING = {"l_hand": "LeftWrist", "r_hand": "RightWrist", "l_ankle": "LeftAnkle", "r_ankle": "RightAnkle"}
FEET = ("LeftToe", "RightToe")


def anim_section(out: str, fast: bool, lines: list[str]) -> None:
    import jax
    import numpy as np

    from .. import anim, ik, viz

    walk = anim.cmu_walk()
    if fast:  # 2 s of walking (frames 540-780, along +z)
        walk = anim.Motion(skeleton=walk.skeleton, rotations=walk.rotations[540:780],
                           root_positions=walk.root_positions[540:780], frame_time=walk.frame_time,
                           channels=walk.channels, end_sites=walk.end_sites)
    T = walk.num_frames
    print(f"[demo] anim: the CMU walk ({T} frames at 120 fps): foot contacts and locking ...", flush=True)
    down = anim.foot_contacts(walk, FEET)
    t0 = time.perf_counter()
    locked = jax.block_until_ready(anim.lock_feet(walk, FEET, down))
    lock_s = time.perf_counter() - t0
    before, after = anim.foot_slide(walk, FEET, down), anim.foot_slide(locked, FEET, down)
    print("[demo] anim: retargeting onto ik.humanoid() ...", flush=True)
    H = ik.humanoid()
    t0 = time.perf_counter()
    r = jax.block_until_ready(anim.retarget(locked, H, MAPPING))
    ret_s = time.perf_counter() - t0
    err = np.asarray(r.error)
    print("[demo] anim: drawing anim_walk.gif ...", flush=True)
    Pc, Ph = np.asarray(anim.positions(locked)), np.asarray(anim.positions(r.motion))
    shift = np.array([0.9, 0.0, 0.0])  # the two figures side by side in the front view
    P = np.concatenate([Pc - shift, Ph + shift], axis=1)
    J = walk.skeleton.num_joints
    parents = walk.skeleton.parents + tuple(J if p < 0 else p + J for p in H.parents)
    toes = tuple(walk.skeleton.index(f) for f in FEET) + tuple(J + H.index(n) for n in ("l_toe", "r_toe"))
    viz.animate_skeleton(parents, P, os.path.join(out, "anim_walk.gif"), effectors=toes, views=("front", "side"),
                         stride=20 if fast else 12, fps=15,
                         title="CMU 131_01, feet locked (left), retargeted onto ik.humanoid() (right)")
    lines += ["## Animation: the CMU walk (BVH), feet locked, retargeted onto the humanoid", "",
              "| frames | toe slide before (mm) | after (mm) | lock_feet (s, compile included) | retarget error p95 (mm) | "
              "frames converged | retarget (s, compile included) | file |", "|---|---|---|---|---|---|---|---|",
              f"| {T} | {1e3 * before.max():.1f} | {1e3 * after.max():.2g} | {lock_s:.1f} | "
              f"{1e3 * np.percentile(err, 95):.1f} | {100 * float(np.mean(r.converged)):.0f}% | {ret_s:.1f} | "
              "anim_walk.gif |", ""]
