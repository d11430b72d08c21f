"""Demo section: a strip piling onto itself, with self-contact (``cloth_pile.gif``)."""

from __future__ import annotations

import os

from .demo_contact import _run


def strip(width: int, length: int, spacing: float = 0.04, tilt: float = 20.0):
    """``(V (N, 3), T (F, 3))``: a strip of ``width x (length + 1)`` particles ``spacing``
    apart (m), standing on its end 1 cm above the floor, leaning ``tilt`` degrees from the
    vertical (towards +z) and bent slightly out of plane, so that it falls, buckles where it
    meets the floor and piles onto itself."""
    import numpy as np

    u, h = np.meshgrid(np.arange(width) * spacing, np.arange(length + 1) * spacing, indexing="ij")
    u, h = u.reshape(-1), h.reshape(-1)
    a = np.deg2rad(tilt)
    bend = 0.002 * np.sin(7 * h)
    V = np.stack([u - 0.5 * spacing * (width - 1), 0.01 + h * np.cos(a) - bend * np.sin(a),
                  h * np.sin(a) + bend * np.cos(a)], -1)
    idx = np.arange(width * (length + 1)).reshape(width, length + 1)
    T = np.concatenate([np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:]], -1).reshape(-1, 3),
                        np.stack([idx[:-1, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 3)])
    return V, T


def pile_section(out: str, fast: bool, lines: list[str]) -> None:
    import numpy as np

    from .. import cloth, viz
    from ..cloth._self.intersect import crossings

    width, length = (3, 12) if fast else (6, 30)
    steps = 30 if fast else 105
    V, T = strip(width, length)
    floor = cloth.Plane(np.array([0.0, 1.0, 0.0]), 0.0, friction=0.3)
    c = cloth.from_mesh(V, T, stiffness=100.0, bending=0.5, density=0.5, colliders=(floor,), self_contact=True)
    print(f"[demo] self-contact: a {len(V)}-particle strip falling onto the floor, {steps} steps ...", flush=True)
    xs, infos, compile_s, run_s, gap = _run(c, steps, 1 / 60)
    bad = sum(crossings(x, c.contact_faces, c.contact_edges).shape[0] > 0 for x in xs)
    print("[demo] self-contact: drawing cloth_pile.gif ...", flush=True)
    viz.animate_surface(xs, T, os.path.join(out, "cloth_pile.gif"), colliders=c.colliders, stride=3 if fast else 2,
                        title="a strip piling onto itself (self-contact)", elev=20.0)
    lines += ["## Cloth self-contact (point-triangle and edge-edge barriers, additive CCD)", "",
              "| scene | particles | steps | ms/step | compile (s) | mean Newton | most substeps | converged | "
              "frames intersecting | min distance to floor (m) | file |",
              "|---|---|---|---|---|---|---|---|---|---|---|",
              f"| strip piling onto itself | {c.num_particles} | {steps} | {1e3 * run_s / steps:.1f} | {compile_s:.1f} | "
              f"{float(np.mean(infos.newton_iters)):.1f} | {int(np.max(infos.substeps))} | "
              f"{float(np.mean(infos.converged)):.0%} | {bad} | {gap:.1e} | cloth_pile.gif |", ""]
