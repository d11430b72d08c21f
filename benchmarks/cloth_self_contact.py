"""Self-contact: two cloth layers draped on a sphere, with and without ``self_contact``.

Two ``n x n`` layers 1.0 m across (0.25 kg each, k = 1e3, damping 0.01), 3 cm apart and
shifted 1 cm against each other, dropped from rest 0.1 m above a sphere (radius 0.35,
friction 0.4), dt = 1/60, float64 and float32.  Each case runs the default
``ImplicitEuler()`` on the scene with ``self_contact=True`` and on the same scene
without, alternated in one process (warm rollouts, compile apart), and with self-contact
and ``newton_iters=100`` (``--iters``: more iterations before a step splits into
substeps; ``cost`` is against the default scene without self-contact): ms per step, the
share of steps converged, substeps, Newton iterations, the frames in which some edge
passes through a triangle (``jaxsim.cloth._self.intersect``), and the least distance
between the layers.

Side by side, in the same run: Newton's VBD (the ``newton`` package, a bench extra; Warp on
the CPU) on the same two layers with its self-contact on (``particle_enable_self_contact``,
interaction distance our ``contact_gap``, as much again of detection slack), the same
sphere and floor with friction 0.4, ``iterations=10``, at 1, 2, 5, 10 and 20 substeps a
frame until a run is stable (finite, every particle centre outside the sphere and above
the floor), leaves no intersecting frame and falls as the layers should: VBD caps each
vertex's motion per substep by a bound near its self-contact distance, so at few
substeps the layers sink slowly instead of falling.  "fall" is the layers' mean drop over
the first 0.1 s (before they reach the sphere) over free fall's ``g t^2 / 2``, for both
solvers.  Per row: ms per step (per frame), and the frames in which some edge passes
through a triangle, by the same checker on VBD's own triangles.

Run: ``python benchmarks/cloth_self_contact.py [--quick] [--n 32] [--steps 60] [--dtypes float32] [--iters 100] [--no-vbd]``;
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
from cloth_vbd import Frames  # noqa: E402

from jaxsim import cloth as C  # noqa: E402
from jaxsim.cloth._model.scene import check_faces  # noqa: E402
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


#: Frames over which the layers fall freely (0.1 s: they reach the sphere after 0.14 s).
FALL_FRAMES = 6


def fall_ratio(h0, h, g):
    """The mean drop from heights ``h0`` to ``h`` (``(N,)``, m) over ``FALL_FRAMES`` frames,
    over free fall's."""
    t = FALL_FRAMES / 60
    return float(np.mean(h0 - h) / (0.5 * g * t * t))


def vbd(n, steps, dhat, substeps):
    """Newton's VBD on the two layers (z up), with its self-contact on."""
    import newton
    import warp as wp

    wp.config.quiet = True
    span = 1.0
    b = newton.ModelBuilder()
    cfg = b.default_shape_cfg.copy()
    cfg.mu = 0.4
    b.add_ground_plane(cfg=cfg)
    b.add_shape_sphere(-1, xform=wp.transform(wp.vec3(0.0, 0.0, 0.5), wp.quat_identity()), radius=0.35, cfg=cfg)
    for dx, height in ((0.0, 0.98), (0.01, 0.95)):
        b.add_cloth_grid(pos=wp.vec3(-span / 2 + dx, -span / 2 + dx, height), rot=wp.quat_identity(),
                         vel=wp.vec3(0.0, 0.0, 0.0), dim_x=n - 1, dim_y=n - 1, cell_x=span / (n - 1),
                         cell_y=span / (n - 1), mass=0.25 / n**2, tri_ke=1e3, tri_ka=1e3, tri_kd=1e-2,
                         edge_ke=1e-2, particle_radius=0.005)
    b.color(include_bending=True)
    model = b.finalize(device="cpu")
    model.soft_contact_mu = 0.4
    solver = newton.solvers.SolverVBD(model=model, iterations=10, particle_enable_self_contact=True,
                                      particle_self_contact_margin=dhat, particle_self_contact_gap=dhat)
    sim = Frames(newton, model, solver, substeps, fps=60)
    t0 = time.perf_counter()
    sim.frame()  # Warp builds its kernels on the first use
    wp.synchronize()
    build = time.perf_counter() - t0
    run, frames = 0.0, [sim.q]  # after frame 1
    for _ in range(steps - 1):
        t0 = time.perf_counter()
        sim.frame()
        wp.synchronize()
        run += time.perf_counter() - t0
        frames.append(sim.q)
    X = np.stack(frames).astype(np.float64)
    faces = model.tri_indices.numpy()
    edges = check_faces(faces, X.shape[1], True)[1]  # the unique edges, as a scene derives them
    finite = bool(np.all(np.isfinite(X)))
    bad = [t for t in range(steps) if finite and crossings(X[t], faces, edges).shape[0]]
    gap = min(float(np.linalg.norm(X - np.array([0.0, 0.0, 0.5]), axis=-1).min()) - 0.35, float(X[..., 2].min()))
    fall = fall_ratio(model.particle_q.numpy()[:, 2], X[FALL_FRAMES - 1, :, 2], 9.81)
    return {"n": n, "particles": int(model.particle_count), "solver": "newton VBD", "dtype": "float32",
            "self_contact": True, "steps": steps, "substeps_per_frame": substeps,
            "ms_per_step": 1e3 * run / (steps - 1), "compile_s": build,
            "stable": finite and gap >= 0.0, "closest_collider_m": gap, "fall": fall,
            "frames_intersecting": len(bad) if finite else None, "first_intersecting_frame": bad[0] if bad else None}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="16x16 layers, 30 steps")
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--dtypes", default="float64,float32")
    ap.add_argument("--no-vbd", action="store_true", help="leave Newton's VBD out")
    ap.add_argument("--iters", default="100",
                    help="more Newton iterations before a split, with self-contact (comma list; '' for none)")
    a = ap.parse_args()
    n, steps = (16, 30) if a.quick else (a.n, a.steps)
    rows = []
    for dtype in [np.dtype(d).type for d in a.dtypes.split(",")]:
        cases = {}
        # (self-contact, newton_iters): the default both ways, and with more iterations an
        # attempt before it splits into substeps (ImplicitEuler's newton_iters)
        keys = [(True, None), (False, None)] + [(True, int(k)) for k in a.iters.split(",") if k]
        for on, iters in keys:
            c = layers(n, dtype, on)
            s0 = C.State.at_rest(c)
            integ = C.ImplicitEuler() if iters is None else C.ImplicitEuler(newton_iters=iters)
            f = jax.jit(lambda s, c=c, integ=integ: C.rollout(c, s, 1 / 60, steps, integ))
            t0 = time.perf_counter()
            out = jax.block_until_ready(f(s0))
            cases[on, iters] = {"scene": c, "f": f, "s0": s0, "first_s": time.perf_counter() - t0, "runs": [], "out": out}
        for _ in range(a.rounds):  # alternated warm runs
            for key in keys:
                k = cases[key]
                t0 = time.perf_counter()
                jax.block_until_ready(k["f"](k["s0"]))
                k["runs"].append(time.perf_counter() - t0)
        off_ms = None
        for on, iters in keys:
            k = cases[on, iters]
            states, info = k["out"]
            X = np.asarray(states.x, np.float64)
            c = k["scene"]
            ref = cases[True, None]["scene"]  # the same triangles, for the scene without self-contact too
            faces, edges = ref.contact_faces, ref.contact_edges
            bad = [t for t in range(steps) if crossings(X[t], faces, edges).shape[0]]
            run = float(np.median(k["runs"]))
            row = {"n": n, "particles": c.num_particles, "solver": "jaxsim ImplicitEuler", "dtype": np.dtype(dtype).name,
                   "self_contact": on, "newton_iters": iters,
                   "steps": steps, "ms_per_step": 1e3 * run / steps, "compile_s": max(k["first_s"] - run, 0.0),
                   "converged_share": float(np.mean(info.converged)), "stable": bool(np.all(info.stable)),
                   "substeps_max": int(np.max(info.substeps)), "newton_per_step": float(np.mean(info.newton_iters)),
                   "cg_per_newton": float(np.sum(info.cg_iters) / max(1, np.sum(info.newton_iters))),
                   "frames_intersecting": len(bad), "first_intersecting_frame": bad[0] if bad else None,
                   "least_layer_gap_m": min(layer_gap(X[t], n) for t in range(0, steps, max(1, steps // 10))),
                   "fall": fall_ratio(np.asarray(k["s0"].x)[:, 1], X[FALL_FRAMES - 1, :, 1], 9.8),
                   "pair_overflow": bool(np.any(info.pair_overflow)) if on else None}
            rows.append(row)
            if not on:
                off_ms = row["ms_per_step"]
        for row in rows[-len(keys):]:
            if row["self_contact"]:
                row["cost_ratio"] = row["ms_per_step"] / off_ms
            print(row, flush=True)
        print(f"{np.dtype(dtype).name}: self-contact costs {rows[-len(keys)]['cost_ratio']:.2f}x", flush=True)
    if not a.no_vbd:
        dhat = float(layers(n, np.float32, True).contact_gap)
        for sub in (1, 2, 5, 10, 20):
            rows.append(vbd(n, steps, dhat, sub))
            print(rows[-1], flush=True)
            if rows[-1]["stable"] and rows[-1]["frames_intersecting"] == 0 and rows[-1]["fall"] >= 0.9:
                break
    name = "cloth_self_contact" + ("_quick" if a.quick else "")
    write(name, {"rows": rows, "dt": 1 / 60, "quick": bool(a.quick), "rounds": a.rounds})


if __name__ == "__main__":
    main()
