"""Demo section: cloth meeting colliders (``cloth_sphere.gif``, ``cloth_floor.gif``)."""

from __future__ import annotations

import os

from ._timing import timed


def _run(scene, steps, dt):
    import numpy as np

    from .. import cloth

    s0 = cloth.State.at_rest(scene)
    (states, infos), compile_s, run_s = timed(lambda: cloth.rollout(scene, s0, dt, steps), again=False)
    xs = np.concatenate([np.asarray(s0.x)[None], np.asarray(states.x)])
    gap = min(float(np.min(np.asarray(c.distance(states.x)))) for c in scene.colliders)
    return xs, infos, compile_s, run_s, gap


def _row(name, scene, steps, infos, compile_s, run_s, gap, gif):
    import numpy as np

    return (f"| {name} | {scene.num_particles} | {steps} | {1e3 * run_s / steps:.2f} | {compile_s:.1f} | "
            f"{float(np.mean(infos.newton_iters)):.1f} | {float(np.mean(infos.cg_iters)):.0f} | "
            f"{float(np.mean(infos.converged)):.0%} | {gap:.1e} | {gif} |")


def contact_section(out: str, fast: bool, lines: list[str]) -> None:
    import numpy as np

    from .. import cloth, viz

    dt = 1 / 60
    n = 12 if fast else 24
    span = 1.2
    sphere = cloth.Sphere(np.array([0.0, 0.5, 0.0]), 0.35, friction=0.4)
    floor = cloth.Plane(np.array([0.0, 1.0, 0.0]), 0.0, friction=0.4)
    sq = cloth.grid(n, span / n, origin=(-span / 2, 0.95, -span / 2), mass=0.3 / (n + 1) ** 2, stiffness=300.0,
                    damping=0.01, gravity=9.8, pins=[], colliders=(sphere, floor))
    steps = 60 if fast else 150
    print(f"[demo] contact: {(n + 1) ** 2}-particle cloth onto a sphere, {steps} steps ...", flush=True)
    xs, infos, compile_s, run_s, gap = _run(sq, steps, dt)
    viz.animate_surface(xs, cloth.grid_triangles(n), os.path.join(out, "cloth_sphere.gif"), colliders=sq.colliders,
                        stride=3 if fast else 2, title="cloth on a sphere, friction 0.4", elev=8.0)
    rows = [_row("square cloth onto a sphere", sq, steps, infos, compile_s, run_s, gap, "cloth_sphere.gif")]

    V, T = cloth.read_obj(cloth.TABLECLOTH_OBJ)
    roller = cloth.Capsule(np.array([-0.7, 0.12, 0.0]), np.array([0.7, 0.12, 0.0]), 0.12, friction=0.3)
    table = cloth.from_mesh(V + np.array([0.0, 0.6, 0.0]), T, stiffness=200.0, density=0.3, damping=0.01,
                            colliders=(floor, roller))
    steps = 60 if fast else 150
    print(f"[demo] contact: tablecloth.obj ({len(V)} vertices) onto a floor and a capsule, {steps} steps ...",
          flush=True)
    xs, infos, compile_s, run_s, gap = _run(table, steps, dt)
    viz.animate_surface(xs, T, os.path.join(out, "cloth_floor.gif"), colliders=table.colliders,
                        stride=3 if fast else 2, title="tablecloth.obj onto a floor and a capsule", elev=25.0)
    rows.append(_row("tablecloth.obj onto floor + capsule", table, steps, infos, compile_s, run_s, gap,
                     "cloth_floor.gif"))
    lines += ["## Cloth with colliders (IPC barrier, friction, no penetration)", "",
              "| scene | particles | steps | ms/step | compile (s) | mean Newton | mean CG | converged | "
              "min distance (m) | file |", "|---|---|---|---|---|---|---|---|---|---|", *rows, ""]
