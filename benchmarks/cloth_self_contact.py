"""Self-contact: two cloth layers draped on a sphere, with and without ``self_contact``.

Two ``n x n`` layers 1.0 m across (0.25 kg each, k = 1e3, damping 0.01), 3 cm apart and
shifted 1 cm against each other, dropped from rest 0.1 m above a sphere (radius 0.35,
friction 0.4), dt = 1/60, float64 and float32.  Each case runs the default
``ImplicitEuler()`` on the scene with ``self_contact=True`` and on the same scene
without, alternated in one process (warm rollouts, compile apart): ms per step, the
share of steps converged, substeps, Newton iterations, the frames in which some edge
passes through a triangle (``jaxsim.cloth._self.intersect``), and the least distance
between the layers.

Run: ``python benchmarks/cloth_self_contact.py [--quick] [--n 32] [--steps 60] [--dtypes float32]``;
writes ``benchmarks/results/cloth_self_contact.json`` (``--quick``: 16x16 layers over 30 steps,
``cloth_self_contact_quick.json``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import write  # noqa: E402

from jaxsim import cloth as C  # noqa: E402
from jaxsim.cloth._self.intersect import crossings  # noqa: E402


def layers(n, dtype, self_contact):
    span = 1.0
    top = C.grid(n - 1, span / (n - 1), origin=(-span / 2, 0.98, -span / 2)).rest
    low = C.grid(n - 1, span / (n - 1), origin=(-span / 2 + 0.01, 0.95, -span / 2 + 0.01)).rest
    T1 = C.grid_triangles(n - 1)
    V = np.concatenate([top, low])
    T = np.concatenate([T1, T1 + n * n])
    sphere = C.Sphere(np.array([0.0, 0.5, 0.0]), 0.35, friction=0.4)
    c = C.from_mesh(V, T, stiffness=1e3, damping=0.01, density=0.25, dtype=dtype, colliders=(sphere,),
                    self_contact=self_contact)
    return c


def layer_gap(x, n):
    """Least distance (m) from a particle of the upper layer to one of the lower layer."""
    top, low = x[: n * n], x[n * n:]
    best = np.inf
    for i in range(0, len(top), 256):
        d = np.linalg.norm(top[i:i + 256, None] - low[None], axis=-1)
        best = min(best, float(d.min()))
    return best


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="16x16 layers, 30 steps")
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--dtypes", default="float64,float32")
    a = ap.parse_args()
    n, steps = (16, 30) if a.quick else (a.n, a.steps)
    rows = []
    for dtype in [np.dtype(d).type for d in a.dtypes.split(",")]:
        cases = {}
        for on in (True, False):
            c = layers(n, dtype, on)
            s0 = C.State.at_rest(c)
            f = jax.jit(lambda s, c=c: C.rollout(c, s, 1 / 60, steps))
            t0 = time.perf_counter()
            out = jax.block_until_ready(f(s0))
            cases[on] = {"scene": c, "f": f, "s0": s0, "first_s": time.perf_counter() - t0, "runs": [], "out": out}
        for _ in range(a.rounds):  # alternated warm runs
            for on in (True, False):
                k = cases[on]
                t0 = time.perf_counter()
                jax.block_until_ready(k["f"](k["s0"]))
                k["runs"].append(time.perf_counter() - t0)
        for on in (True, False):
            k = cases[on]
            states, info = k["out"]
            X = np.asarray(states.x, np.float64)
            c = k["scene"]
            ref = cases[True]["scene"]  # the same triangles, for the scene without self-contact too
            faces, edges = ref.contact_faces, ref.contact_edges
            bad = [t for t in range(steps) if crossings(X[t], faces, edges).shape[0]]
            run = float(np.median(k["runs"]))
            row = {"n": n, "particles": c.num_particles, "dtype": np.dtype(dtype).name, "self_contact": on,
                   "steps": steps, "ms_per_step": 1e3 * run / steps, "compile_s": max(k["first_s"] - run, 0.0),
                   "converged_share": float(np.mean(info.converged)), "stable": bool(np.all(info.stable)),
                   "substeps_max": int(np.max(info.substeps)), "newton_per_step": float(np.mean(info.newton_iters)),
                   "cg_per_newton": float(np.sum(info.cg_iters) / max(1, np.sum(info.newton_iters))),
                   "frames_intersecting": len(bad), "first_intersecting_frame": bad[0] if bad else None,
                   "least_layer_gap_m": min(layer_gap(X[t], n) for t in range(0, steps, max(1, steps // 10))),
                   "pair_overflow": bool(np.any(info.pair_overflow)) if on else None}
            rows.append(row)
            print(row, flush=True)
        on_ms = rows[-2]["ms_per_step"]
        off_ms = rows[-1]["ms_per_step"]
        rows[-2]["cost_ratio"] = on_ms / off_ms
        print(f"{np.dtype(dtype).name}: self-contact costs {on_ms / off_ms:.2f}x", flush=True)
    name = "cloth_self_contact" + ("_quick" if a.quick else "")
    write(name, {"rows": rows, "dt": 1 / 60, "quick": bool(a.quick), "rounds": a.rounds})


if __name__ == "__main__":
    main()
