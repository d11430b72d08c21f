"""Cloth A/B: this checkout's steps against a baseline revision's, alternated in one process.

The baseline's ``jaxsim`` is extracted from git and imported as ``jaxsim_baseline``
(``_common.baseline_package``).  Each case is a ``rollout`` from the same moving state,
compiled in both (compile time and optimised-HLO fusion count recorded apart), then timed
in alternating rounds (baseline, current, baseline, current, ...; best of a few calls per
round), so machine noise hits both alike; the paired ratio per round is ``baseline time /
current time`` (above 1: the current code is faster).  The end states are compared too.

Cases (float64 unless said, ``benchmarks/cloth_step.py``'s scenes): A the lab cloth (CG, Cholesky,
explicit); B 32x32 and B 128x128 (CG, on planes); C 32x32 k = 1e5 (two-level CG, planes and grid-block
aggregates); the tablecloth mesh (CG and two-level CG: the particle layout, gathers and
voxel aggregates; pinned at its centre and one edge); B 16x16 over a sphere (contact); two 8x8 layers over a
sphere with self-contact, and two 32x32 layers in float32 (their first 20 frames: the fall and the
landing); ``batch_rollout`` of 4 B 16x16 scenes; ``cloth_vbd.py``'s drape onto a
sphere and a floor with friction, default ``ImplicitEuler()``: 32x32 float64 over the first 30
frames, and 64x64 float32 over 15 frames from frame 15 (where it lies on the sphere).

Run: ``python benchmarks/cloth_ab.py --baseline REV [--rounds 5]``; writes
``benchmarks/results/cloth_ab.json``.
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(__file__))
from _common import ab_arguments, baseline_package, run_once, write  # noqa: E402
from cloth_substeps import drape  # noqa: E402

import jaxsim  # noqa: E402


def layers(C, n=8, dtype=np.float64):
    """Two ``n x n`` layers 3 cm apart over a sphere, with self-contact."""
    top = C.grid(n, 0.6 / n, origin=(-0.3, 0.63, -0.3), dtype=dtype).rest
    low = C.grid(n, 0.6 / n, origin=(-0.27, 0.6, -0.28), dtype=dtype).rest
    V = np.concatenate([np.asarray(top), np.asarray(low)])
    T = np.concatenate([C.grid_triangles(n), C.grid_triangles(n) + (n + 1) ** 2])
    return C.from_mesh(V, T, stiffness=300.0, density=0.3, dtype=dtype, self_contact=True,
                       colliders=(C.Sphere(np.array([0.0, 0.25, 0.0]), 0.25),))


_STARTS = {}


def _drape_start(n, dtype, frames):
    """``(x, v)`` numpy: the drape after ``frames`` frames, by this checkout's code (computed once)."""
    key = (n, np.dtype(dtype).name, frames)
    if key not in _STARTS:
        C = jaxsim.cloth
        c = drape(n, dtype, cloth=C)
        states, _ = C.rollout(c, C.State.at_rest(c), 1 / 60, frames, C.ImplicitEuler())
        _STARTS[key] = (np.asarray(states.x[-1]), np.asarray(states.v[-1]))
    return _STARTS[key]


def cases(pkg):
    """``{name: (jitted rollout of a state, the state)}`` for one package."""
    C = pkg.cloth
    out = {}
    lab = C.lab_cloth(np.float64)
    b32 = C.grid(31, 0.2, dtype=np.float64)
    b128 = C.grid(127, 0.2, dtype=np.float64)
    stiff = C.grid(31, 0.2, mass=1.0 / 32**2, stiffness=1e5, gravity=9.8, dtype=np.float64)
    V, T = C.read_obj(C.TABLECLOTH_OBJ)
    mesh = C.from_mesh(V, T, dtype=np.float64, pins=[0, int(np.argmax(V[:, 0]))])  # the centre and one edge
    sphere = C.grid(15, 0.1, origin=(-0.75, 0.5, -0.75), gravity=9.8, pins=[], dtype=np.float64,
                    colliders=(C.Sphere(np.zeros(3), 0.4, friction=0.3),))
    cg, tl = C.ImplicitEuler(linear_solver=C.CG()), C.ImplicitEuler(linear_solver=C.CG(C.TwoLevel()))
    table = [("A lab CG", lab, cg, 1 / 60, 10), ("A lab Cholesky", lab, C.ImplicitEuler(linear_solver=C.Cholesky()),
                                                 1 / 60, 10),
             ("A lab explicit 100 substeps", lab, C.ExplicitEuler(substeps=100), 1 / 60, 10),
             ("B 32x32 CG", b32, cg, 1 / 60, 10), ("B 128x128 CG", b128, cg, 1 / 60, 5),
             ("C 32x32 k=1e5 two-level", stiff, tl, 1 / 30, 5),
             ("tablecloth mesh CG", mesh, cg, 1 / 60, 10), ("tablecloth mesh two-level", mesh, tl, 1 / 60, 10),
             ("B 16x16 on a sphere", sphere, cg, 1 / 60, 10),
             ("2 x 8x8 layers self-contact on a sphere", layers(C), C.ImplicitEuler(), 1 / 60, 20),
             ("2 x 32x32 layers self-contact float32", layers(C, 31, np.float32), C.ImplicitEuler(), 1 / 60, 20)]
    for name, c, integ, dt, n in table:
        s0 = C.State.at_rest(c)
        if not c.colliders:  # start from a moving, deformed state
            states, _ = C.rollout(c, s0, dt, 20, C.ImplicitEuler())
            s0 = C.State(states.x[-1], states.v[-1])
        out[name] = (jax.jit(lambda s, c=c, integ=integ, dt=dt, n=n: C.rollout(c, s, dt, n, integ)), s0)
    for name, n, dtype, start, steps in (("drape 32x32", 32, np.float64, 0, 30),
                                         ("drape 64x64 float32", 64, np.float32, 15, 15)):
        c = drape(n, dtype, cloth=C)
        s0 = C.State.at_rest(c)
        if start:  # the same start for both packages: the current one's rollout, as arrays
            x, v = _drape_start(n, dtype, start)
            s0 = C.State(jnp.asarray(x, dtype), jnp.asarray(v, dtype))
        out[name] = (jax.jit(lambda s, c=c, steps=steps: C.rollout(c, s, 1 / 60, steps, C.ImplicitEuler())), s0)
    small = C.grid(15, 0.2, dtype=np.float64)
    scenes = [C.replace(small, stiffness=k) for k in (50.0, 100.0, 200.0, 400.0)]
    out["batch_rollout 4 x B 16x16"] = (
        jax.jit(lambda s: C.batch_rollout(scenes, s, 1 / 60, 10, cg, sharded=False)), C.State.at_rest(small))
    return out


def main():
    ap = ab_arguments()
    ap.add_argument("--only", default=None, help="run only the cases whose name contains this")
    args = ap.parse_args()
    pkgs = {"baseline": baseline_package(args.baseline), "current": jaxsim}
    built = {k: cases(p) for k, p in pkgs.items()}
    rows = []
    t_all = time.perf_counter()
    for name in built["current"]:
        if args.only and args.only not in name:
            continue
        row = {"case": name}
        ends = {}
        for k in pkgs:
            fn, arg = built[k][name]
            row[f"{k}_compile_s"] = run_once(fn, arg)
            row[f"{k}_hlo_fusions"] = fn.lower(arg).compile().as_text().count(" fusion(")
            states, infos = fn(arg)
            ends[k] = np.asarray(states.x)
            row[f"{k}_newton_iters"] = int(jnp.sum(infos.newton_iters))
            row[f"{k}_cg_iters"] = int(jnp.sum(infos.cg_iters))
        row["max_state_difference"] = float(np.max(np.abs(ends["current"] - ends["baseline"])))
        times = {k: [] for k in pkgs}
        for _ in range(args.rounds):
            for k in pkgs:  # alternated: baseline, current, baseline, current, ...
                fn, arg = built[k][name]
                times[k].append(min(run_once(fn, arg) for _ in range(3)))
        ratios = [b / c for b, c in zip(times["baseline"], times["current"])]
        row.update({f"{k}_s": times[k] for k in pkgs})
        row["ratio_median"] = statistics.median(ratios)
        row["ratio_min"], row["ratio_max"] = min(ratios), max(ratios)
        rows.append(row)
        print(f"{name:30s} fusions {row['baseline_hlo_fusions']:4d} -> {row['current_hlo_fusions']:4d}  "
              f"Newton {row['baseline_newton_iters']} -> {row['current_newton_iters']}  "
              f"diff {row['max_state_difference']:.1e}  ratio {row['ratio_median']:.3f} "
              f"[{row['ratio_min']:.3f}, {row['ratio_max']:.3f}]", flush=True)
    write("cloth_ab", {"baseline": args.baseline, "rounds": args.rounds, "rows": rows,
                       "wall_s": time.perf_counter() - t_all})


if __name__ == "__main__":
    main()
