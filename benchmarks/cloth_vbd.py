"""The drape against Newton's VBD (Vertex Block Descent; the ``newton`` package, a bench extra).

The scene is ``cloth_substeps.py``'s drape: a square cloth of 0.5 kg, 1.2 m across, n x n
particles, k = 1e3, dropped from rest 0.1 m above a sphere (radius 0.35, centre 0.5 m up)
over a floor, friction 0.4, 1 s of frames at 60 fps.  jaxsim: the mass-spring cloth,
default ``ImplicitEuler()``, ``BDF2()`` and ``TRBDF2()``, one step per frame, float32 (the default)
and float64.  VBD: ``newton.ModelBuilder.add_cloth_grid`` with the same particles, mass,
size and placement (its cloth is a triangle membrane, ``tri_ke = tri_ka = k``; z up),
the same sphere and a ground plane with friction 0.4, ``SolverVBD(iterations=10)`` and
its default soft contact, at 1, 2, 5 and 10 substeps per frame until one is stable: every
position finite, and every particle centre outside the sphere and above the floor at
every frame.  Per row: wall seconds and process CPU seconds per simulated second (warm:
jaxsim's compile and Warp's kernel build apart), and the closest approach to a collider.

Run: ``python benchmarks/cloth_vbd.py [--quick]`` (``--quick``: 16x16 and 32x32 only);
writes ``benchmarks/results/cloth_vbd.json``.  Needs ``pip install newton`` (Warp, CPU).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import write  # noqa: E402
from cloth_substeps import drape  # noqa: E402

import jaxsim  # noqa: E402
from jaxsim import cloth as C  # noqa: E402

FRAMES, FPS, SPAN, K, MU = 60, 60, 1.2, 1e3, 0.4
SPHERE_C, SPHERE_R = np.array([0.0, 0.5, 0.0]), 0.35


def _timed(fn):
    """``(result, wall s, process CPU s)`` of ``fn()``."""
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def ours(n, dtype, integ):
    cloth = drape(n, dtype)
    s0 = C.State.at_rest(cloth)
    f = jax.jit(lambda s: C.rollout(cloth, s, 1 / FPS, FRAMES, integ))
    (_, first, _) = _timed(lambda: jax.block_until_ready(f(s0)))
    (states, infos), wall, cpu = _timed(lambda: jax.block_until_ready(f(s0)))
    x = np.asarray(states.x, np.float64)
    gap = min(np.linalg.norm(x - SPHERE_C, axis=-1).min() - SPHERE_R, x[..., 1].min())
    sim_s = FRAMES / FPS
    return {"n": n, "solver": f"jaxsim {type(integ).__name__}", "dtype": np.dtype(dtype).name, "substeps_per_frame": 1,
            "wall_s_per_sim_s": wall / sim_s, "cpu_s_per_sim_s": cpu / sim_s, "compile_s": max(first - wall, 0.0),
            "stable": bool(np.all(np.isfinite(x)) and gap >= 0.0), "closest_m": float(gap),
            "converged_share": float(jnp.mean(infos.converged)), "substeps_total": int(jnp.sum(infos.substeps))}


class Frames:
    """Steps a Newton model by frames of ``substeps`` VBD substeps at ``fps``, its collision
    pipeline run before each substep (``frame()``; ``q``: the particles' positions)."""

    def __init__(self, newton, model, solver, substeps, fps=FPS):
        self.model, self.solver, self.substeps, self.dt = model, solver, substeps, 1 / fps / substeps
        self.s0, self.s1, self.ctrl = model.state(), model.state(), model.control()
        self.pipe = newton.CollisionPipeline(model)
        self.contacts = self.pipe.contacts()

    def frame(self):
        for _ in range(self.substeps):
            self.s0.clear_forces()
            self.pipe.collide(self.s0, self.contacts)
            self.solver.step(self.s0, self.s1, self.ctrl, self.contacts, self.dt)
            self.s0, self.s1 = self.s1, self.s0

    @property
    def q(self):
        return self.s0.particle_q.numpy().copy()


def vbd(n, substeps):
    import newton
    import warp as wp

    wp.config.quiet = True
    b = newton.ModelBuilder()  # z up, g = -9.81 along z
    cfg = b.default_shape_cfg.copy()
    cfg.mu = MU
    b.add_ground_plane(cfg=cfg)
    b.add_shape_sphere(-1, xform=wp.transform(wp.vec3(0.0, 0.0, float(SPHERE_C[1])), wp.quat_identity()),
                       radius=SPHERE_R, cfg=cfg)
    b.add_cloth_grid(pos=wp.vec3(-SPAN / 2, -SPAN / 2, 0.95), rot=wp.quat_identity(), vel=wp.vec3(0.0, 0.0, 0.0),
                     dim_x=n - 1, dim_y=n - 1, cell_x=SPAN / (n - 1), cell_y=SPAN / (n - 1), mass=0.5 / n**2,
                     tri_ke=K, tri_ka=K, tri_kd=1e-2, edge_ke=1e-2, particle_radius=0.005)
    b.color(include_bending=True)
    model = b.finalize(device="cpu")
    model.soft_contact_mu = MU
    solver = newton.solvers.SolverVBD(model=model, iterations=10)
    run = Frames(newton, model, solver, substeps)
    frames = []
    _, build, _ = _timed(lambda: (run.frame(), wp.synchronize()))  # Warp builds its kernels on the first use
    w = c = 0.0
    for _ in range(FRAMES - 1):
        _, dw, dc = _timed(lambda: (run.frame(), wp.synchronize()))
        w, c = w + dw, c + dc
        frames.append(run.q)  # read back outside the timing's share of the work
    x = np.stack(frames)
    sphere = np.array([0.0, 0.0, SPHERE_C[1]])
    gap = min(float(np.linalg.norm(x - sphere, axis=-1).min()) - SPHERE_R, float(x[..., 2].min()))
    sim_s = (FRAMES - 1) / FPS
    return {"n": n, "solver": "newton VBD", "dtype": "float32", "substeps_per_frame": substeps,
            "wall_s_per_sim_s": w / sim_s, "cpu_s_per_sim_s": c / sim_s, "compile_s": build,
            "stable": bool(np.all(np.isfinite(x)) and gap >= 0.0), "closest_m": float(gap)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="16x16 and 32x32 only")
    args = ap.parse_args()
    jaxsim.retain_host_memory()
    import newton

    rows = []
    for n in (16, 32) if args.quick else (16, 32, 64):
        for dtype in (np.float32, np.float64):
            for integ in (C.ImplicitEuler(), C.BDF2(), C.TRBDF2()):
                rows.append(ours(n, dtype, integ))
                print(rows[-1], flush=True)
        for sub in (1, 2, 5, 10):
            rows.append(vbd(n, sub))
            print(rows[-1], flush=True)
            if rows[-1]["stable"]:
                break
    write("cloth_vbd", {"rows": rows, "newton": newton.__version__,
                        "scene": "0.5 kg, 1.2 m square, n x n particles, k 1e3, from rest 0.95 m up onto a sphere "
                                 "(r 0.35 at 0.5 m) over a floor, friction 0.4, 60 frames at 60 fps; VBD: triangle "
                                 "membrane tri_ke = tri_ka = 1e3, iterations 10, default soft contact; stable: finite, "
                                 "every particle centre outside the sphere and above the floor at every frame"})


if __name__ == "__main__":
    main()
