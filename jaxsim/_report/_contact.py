"""Cloth section of the report: contact (IPC barrier) stability row and cost."""

from __future__ import annotations

import time

import jax
import numpy as np

from .. import cloth as C
from ._doc import Doc


def _scene(n, k, colliders):
    return C.grid(n, 0.6 / n, origin=(-0.3, 0.9, -0.3), mass=0.2 / (n + 1) ** 2, stiffness=k, damping=0.01,
                  gravity=9.8, pins=[], dtype=np.float64, colliders=colliders)


def contact_section(doc: Doc) -> None:
    quick = doc.quick
    n = 4 if quick else 15
    ks = (1e2, 1e4) if quick else (1e2, 1e3, 1e4, 1e5)
    dts = (1 / 240, 1 / 30) if quick else (1 / 240, 1 / 120, 1 / 60, 1 / 30)
    steps = 40 if quick else 200
    sphere = C.Sphere(np.array([0.0, 0.5, 0.0]), 0.3, friction=0.3)
    floor = C.Plane(np.array([0.0, 1.0, 0.0]), 0.0, friction=0.3)
    doc.md("## Cloth 5. Contact: a cloth falling onto a sphere and a floor",
           f"{(n + 1) ** 2} particles (total mass 0.2 kg, g = 9.8), sphere radius 0.3 m and a floor, friction 0.3, "
           f"{steps} implicit steps from rest for every stiffness k and time step dt (float64, CG).  Contact is IPC's "
           "barrier in the incremental potential with the line search capped at the earliest time of impact.  "
           "**no penetration** counts the cells whose every particle stayed outside both colliders at every step; "
           "a map cell is **stable** when every step was taken (`StepInfo.stable`), and the share of steps with "
           "`converged` is given.")
    rows = []
    for k in ks:
        for dt in dts:
            doc.progress(f"cloth 5: contact k={k:.0e} dt=1/{round(1 / dt)}")
            c = _scene(n, k, (sphere, floor))
            states, infos = C.rollout(c, C.State.at_rest(c), dt, steps)
            dmin = min(float(np.min(np.asarray(col.distance(states.x)))) for col in c.colliders)
            rows.append({"k": k, "dt": f"1/{round(1 / dt)}", "stable": bool(np.all(infos.stable)),
                         "no_penetration": dmin >= 0.0, "min_distance": dmin,
                         "converged": float(np.mean(infos.converged)),
                         "newton": float(np.mean(infos.newton_iters)), "cg": float(np.mean(infos.cg_iters))})
    doc.table("cloth_contact_map", rows, {"k": "k (N/m)", "dt": "dt (s)", "stable": "stable",
                                          "no_penetration": "no penetration", "min_distance": "min distance (m)",
                                          "converged": "converged", "newton": "mean Newton", "cg": "mean CG"},
              {"k": ".0e", "min_distance": ".1e", "converged": ".0%", "newton": ".1f", "cg": ".0f"})
    doc.facts["contact_cells_without_penetration"] = sum(r["no_penetration"] for r in rows)
    doc.facts["contact_cells"] = len(rows)

    # the cost line: the same cloth and the same draped state, with and without the colliders (the
    # rollout length of the map above, so the contact program is the one already compiled)
    dt = dts[-1]
    c = _scene(n, ks[-1], (sphere, floor))
    warm, _ = C.rollout(c, C.State.at_rest(c), dt, steps)
    s0 = C.State(warm.x[-1], warm.v[-1])
    cost = {}
    for label, sc in (("with", c), ("without", C.replace(c, colliders=()))):
        jax.block_until_ready(C.rollout(sc, s0, dt, steps))
        t0 = time.perf_counter()
        _, infos = jax.block_until_ready(C.rollout(sc, s0, dt, steps))
        cost[label] = (1e3 * (time.perf_counter() - t0) / steps, float(np.mean(infos.newton_iters)),
                       float(np.mean(infos.cg_iters)))
    doc.facts["contact_cost_ratio"] = cost["with"][0] / cost["without"][0]
    doc.md(f"Cost, from the draped state (k = {ks[-1]:.0e}, dt = 1/{round(1 / dt)}, float64): "
           f"{cost['with'][0]:.2f} ms per step with the sphere and floor ({cost['with'][1]:.1f} Newton, "
           f"{cost['with'][2]:.0f} CG iterations per step) against {cost['without'][0]:.2f} ms for the same cloth and "
           f"state without them ({cost['without'][1]:.1f} Newton, {cost['without'][2]:.0f} CG), "
           f"{doc.facts['contact_cost_ratio']:.2f}x.  Without colliders the draped cloth falls and crumples, which "
           "takes its own Newton and CG iterations: the ratio compares whole steps, not the contact terms alone "
           "(`benchmarks/cloth_step.py --only-contact` has the 32x32 case).")
