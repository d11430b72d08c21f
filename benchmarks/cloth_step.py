"""Cloth step cost and accuracy: dense vs CG vs one-Newton vs explicit, against scipy.sparse.

The stiff scenes C also run CG with the two-level preconditioner (``_implicit.coarse``); dense
steps run on A and B 32x32 only.  CG rows use a fixed
tolerance ``CG.tol`` (``CG(forcing=0)``), and the "default forcing" rows the default
inexact-Newton forcing term (``forcing=1e-2``, ``tol=1e-6``: what
``ImplicitEuler(linear_solver=CG())`` does); ``benchmarks/cloth_stiff.py`` compares the two.

Scenes: A the lab cloth; B lab-like grids 32x32, 64x64, 128x128 particles (m=1, k=100,
spacing 0.2, d=0.2, g=0.3, dt=1/60); C stiff grids 32x32, 64x64 with total mass 1,
g=9.8, k=1e3 and 1e5, dt=1/30.  Each scene is first run for 30 steps (10 on C 64x64) so
the measured step starts from a moving, deformed state.

ms/step is the median over repeats of a ``rollout`` divided by its length (compile time
reported apart): 10 steps on A and B, 5 on C 32x32, 2 on C 64x64 and for the slow
baselines (dense, explicit with 1000 substeps), to bring the whole benchmark, contact
included, under 15 minutes on the 2-core CPU (``wall_s`` in the JSON).  For the same
reason C 64x64 runs the two-level preconditioner only (Jacobi CG on the stiff scenes is
measured on C 32x32, at ``cg_tol`` 1e-6), dense one-Newton runs on A only, and explicit
Euler on A, B 32x32, B 128x128 and C 32x32.  Accuracy is ``max|x - x_ref|`` after one step from the same
state, ``x_ref`` a converged float64 Newton step (tol 1e-12); Newton and CG iterations
and ``converged`` are per-step means (all steps) over the timed rollout, whose steps
start from the extrapolated guess (``ImplicitEuler.extrapolate``; the one-Newton
rows are the lab's linearised step from ``x^n``; "linear start", on A and B, is the
default with ``extrapolate=1``: the constant-acceleration start only, never the
constant-jerk one).  Converged rows stop on the gradient test alone
(``ImplicitEuler(tol=None)``, the default).  The scipy reference
is a Newton loop on the analytic Hessian with ``spsolve``, written here, iterated to
the lab's step test (1e-6 m/s).

Contact (``--only-contact`` runs just this part and updates the JSON's ``contact``
rows): a 32x32 cloth, 1.6 m wide, g = 9.8, falling onto a sphere (radius 0.4, friction
0.3) for 30 steps, then 10 converged float64 CG steps of it draped, against the same
cloth and state without the sphere, in the same run.  Two scenes: B-like (1 kg per
particle, k = 100, dt = 1/60) and C (total mass 1, k = 1e3, dt = 1/30, stiff).  Reported: ms per step, Newton and CG iterations
per step, and active contacts (particles closer than ``dhat`` to the sphere).

Run: ``python benchmarks/cloth_step.py [--quick] [--only-contact]``; writes ``benchmarks/results/cloth_step.json``.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

sys.path.insert(0, __import__("os").path.dirname(__file__))
from _common import time_call, write  # noqa: E402

import jaxsim  # noqa: E402
from jaxsim import cloth as C  # noqa: E402

PRE = {"jacobi": C.Jacobi(), "two_level": C.TwoLevel()}


def scenes(quick):
    out = {"A lab 11x11": (C.lab_cloth(), 1 / 60)}
    for n in ((32,) if quick else (32, 64, 128)):
        out[f"B {n}x{n}"] = (C.grid(n - 1, 0.2), 1 / 60)
    for n in ((32,) if quick else (32, 64)):
        for k in (1e3, 1e5):
            N = n * n
            out[f"C {n}x{n} k={k:.0e}"] = (C.grid(n - 1, 0.2, mass=1.0 / N, stiffness=k, gravity=9.8), 1 / 30)
    return out


def slow_baseline(label):
    """Rows timed over 2 steps whatever the scene (each step takes 0.3 s or more)."""
    return label.startswith("dense") or label == "explicit substeps=1000"


def scipy_newton(c, x0, v0, h, tol, iters=50):
    """Newton on (17.19) + implicit damping with the analytic spring Hessian, scipy spsolve."""
    springs, L, k = np.asarray(c.springs), np.asarray(c.rest_length), np.asarray(c.stiffness)
    m, g, d = np.asarray(c.mass), np.asarray(c.gravity), float(c.damping)
    N = len(m)
    fd = np.repeat(~np.asarray(c.pinned), 3)
    i, j = springs[:, 0], springs[:, 1]
    y = x0 + h * v0 + h * h * g
    d0 = x0[j] - x0[i]
    e0 = d0 / np.linalg.norm(d0, axis=1, keepdims=True)
    rr = np.stack([3 * i + a for a in range(3)], 1)
    cc = np.stack([3 * j + a for a in range(3)], 1)
    x = x0.copy()
    n_it = 0
    for n_it in range(1, iters + 1):
        dx01 = x[j] - x[i]
        l = np.linalg.norm(dx01, axis=1)
        e = dx01 / l[:, None]
        f = (k * (l - L))[:, None] * e
        s = np.sum(e0 * (dx01 - d0), axis=1) * d / h
        f = f + s[:, None] * e0
        grad = m[:, None] * (x - y) / h**2
        np.add.at(grad, i, -f)
        np.add.at(grad, j, f)
        eeT = e[:, :, None] * e[:, None, :]
        A = k[:, None, None] * eeT + np.maximum(k * (1 - L / l), 0)[:, None, None] * (np.eye(3) - eeT)
        A = A + (d / h) * e0[:, :, None] * e0[:, None, :]
        R = np.concatenate([rr[:, :, None].repeat(3, 2), cc[:, :, None].repeat(3, 2), rr[:, :, None].repeat(3, 2), cc[:, :, None].repeat(3, 2)])
        Cc = np.concatenate([rr[:, None, :].repeat(3, 1), cc[:, None, :].repeat(3, 1), cc[:, None, :].repeat(3, 1), rr[:, None, :].repeat(3, 1)])
        V = np.concatenate([A, A, -A, -A])
        H = sp.coo_matrix((V.ravel(), (R.ravel(), Cc.ravel())), shape=(3 * N, 3 * N)).tocsr() + sp.diags(np.repeat(m, 3) / h**2)
        dx = np.zeros(3 * N)
        dx[fd] = spla.spsolve(H[fd][:, fd].tocsc(), -grad.reshape(-1)[fd])
        x = x + dx.reshape(N, 3)
        if np.max(np.abs(dx)) / h < tol:
            break
    return x, n_it


def contact_rows():
    """Both contact scenes (module doc)."""
    return (contact_case("B", mass=1.0, k=100.0, dt=1 / 60)
            + contact_case("C", mass=1.0 / 32**2, k=1e3, dt=1 / 30))


def contact_case(tag, mass, k, dt, n=32, steps=10):
    """The draped-on-a-sphere scene against the same cloth without contact (module doc)."""
    sphere = C.Sphere(jnp.array([0.0, 0.5, 0.0]), 0.4, friction=0.3)
    span = 1.6
    base = C.grid(n - 1, span / (n - 1), origin=(-span / 2, 1.0, -span / 2), mass=mass, stiffness=k,
                  gravity=9.8, pins=[], dtype=np.float64)
    draped = C.replace(base, colliders=(sphere,))
    integ = C.ImplicitEuler(linear_solver=C.CG())
    warm, _ = C.rollout(draped, C.State.at_rest(draped), dt, 30, integ)
    s0 = C.State(warm.x[-1], warm.v[-1])
    rows = []
    for label, sc in (("no contact", base), ("sphere contact", draped)):
        fn = jax.jit(lambda s, sc=sc: C.rollout(sc, s, dt, steps, integ))
        tm = time_call(fn, s0, repeats=5, budget=10.0)
        states, info = fn(s0)
        active = int(jnp.sum(sphere.distance(states.x[-1]) < draped.contact_gap))
        row = {"scene": f"{tag} {n}x{n} m={mass:.0e} k={k:.0e} dt=1/{round(1 / dt)} on a sphere", "N": n * n, "method": label, "dtype": "float64",
               "ms_per_step": 1e3 * tm["run_s"] / steps, "compile_s": tm["compile_s"],
               "newton_per_step": float(jnp.mean(info.newton_iters)), "cg_per_step": float(jnp.mean(info.cg_iters)),
               "converged": float(jnp.mean(info.converged)), "active_contacts": active if sc is draped else 0,
               "min_distance": float(jnp.min(sphere.distance(states.x)))}
        rows.append(row)
    rows[1]["cost_vs_no_contact"] = rows[1]["ms_per_step"] / rows[0]["ms_per_step"]
    for r in rows:
        print(f"{r['scene']:44s} {r['method']:15s} {r['ms_per_step']:8.2f} ms/step  newton {r['newton_per_step']:.1f}  "
              f"cg {r['cg_per_step']:.0f}  contacts {r['active_contacts']}  converged {r['converged']:.0%}", flush=True)
    return rows


def main():
    jaxsim.retain_host_memory()  # benchmarks/host_memory.py: what this changes
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only-contact", action="store_true", help="run the contact rows only and update the JSON")
    args = ap.parse_args()
    if args.only_contact:
        import json
        import os
        path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "cloth_step.json")
        old = json.load(open(path)) if os.path.exists(path) else {"rows": [], "quick": args.quick, "complete": False}
        old["contact"] = contact_rows()
        write("cloth_step", {k: v for k, v in old.items() if k not in ("benchmark", "machine", "timestamp")})
        return
    rows = []
    T0 = time.perf_counter()
    for name, (scene, dt) in scenes(args.quick).items():
        N = scene.num_particles
        stiff = name.startswith("C")
        big_stiff = stiff and N > 32 * 32
        n_scene = 2 if big_stiff else 5 if stiff else 10
        pre = C.TwoLevel() if stiff else C.Jacobi()
        warm, _ = C.rollout(scene, C.State.at_rest(scene), dt, 10 if big_stiff else 30,
                            C.ImplicitEuler(linear_solver=C.CG(pre, tol=1e-10), tol=1e-8))
        s0 = C.State(warm.x[-1], warm.v[-1])
        ref, _ = C.step(scene, s0, dt, C.ImplicitEuler(linear_solver=C.CG(pre, tol=1e-13, max_iters=5000), tol=1e-12,
                                                       newton_iters=50))
        ref_x = np.asarray(ref.x)
        t0 = time.perf_counter()
        x_sp, it_sp = scipy_newton(scene, np.asarray(s0.x), np.asarray(s0.v), dt, 1e-6)
        t_sp = time.perf_counter() - t0
        sp_row = {"scene": name, "N": N, "method": "scipy spsolve Newton (tol 1e-6)", "ms_per_step": 1e3 * t_sp,
                  "newton": it_sp, "error_vs_ref": float(np.max(np.abs(x_sp - ref_x)))}
        rows.append(sp_row)
        print(f"{name:22s} {sp_row['method']:34s} {sp_row['ms_per_step']:9.3f} ms  err {sp_row['error_vs_ref']:.1e}", flush=True)
        settings = []
        if N <= 32 * 32 and not stiff:  # dense on C 32x32 took 5.7-5.9 s per step (an earlier run)
            settings.append(("dense converged", C.ImplicitEuler(linear_solver=C.Cholesky())))
            if N < 32 * 32:
                settings.append(("dense one-Newton", C.ImplicitEuler(linear_solver=C.Cholesky(), newton_iters=1, line_search=False, extrapolate=False)))
        pcs = ("two_level",) if big_stiff else ("jacobi", "two_level") if stiff else ("jacobi",)
        for pc in pcs:
            for ct in ((1e-2, 1e-6) if N <= 64 * 64 and not (stiff and pc == "jacobi") else (1e-6,)):
                settings.append((f"cg converged cg_tol={ct:.0e}" + (" two-level" if pc != "jacobi" else ""),
                                 C.ImplicitEuler(linear_solver=C.CG(PRE[pc], tol=ct, forcing=0.0))))
            settings.append(("cg converged default forcing" + (" two-level" if pc != "jacobi" else ""),
                             C.ImplicitEuler(linear_solver=C.CG(PRE[pc]))))
        if not stiff:  # the default's start against the constant-acceleration one alone, same run
            settings.append(("cg converged linear start", C.ImplicitEuler(linear_solver=C.CG(), extrapolate=1)))
        settings.append(("cg one-Newton cg_tol=1e-6", C.ImplicitEuler(linear_solver=C.CG(tol=1e-6), newton_iters=1, line_search=False, extrapolate=False)))  # the lab's linearised step
        for sub in ((10, 1000) if N <= 32 * 32 else (100,) if N > 64 * 64 else ()):
            settings.append((f"explicit substeps={sub}", C.ExplicitEuler(substeps=sub)))
        for label, integ in settings:
            for dtype in (np.float64, np.float32):
                if dtype == np.float32 and not label.startswith(("cg converged cg_tol=1e-06", "cg converged default")):
                    continue
                sc = jax.tree_util.tree_map(lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, scene)
                st = C.State(s0.x.astype(dtype), s0.v.astype(dtype))
                n_steps = 2 if slow_baseline(label) else n_scene
                fn = jax.jit(lambda s, sc=sc, integ=integ, n=n_steps: C.rollout(sc, s, dt, n, integ))
                tm = time_call(fn, st, repeats=5, budget=10.0)
                one, _ = C.step(sc, st, dt, integ)
                err = float(np.max(np.abs(np.asarray(one.x, np.float64) - ref_x)))
                _, info = fn(st)  # the timed rollout's steps (after the first, from the extrapolated start)
                row = {"scene": name, "N": N, "method": label, "dtype": np.dtype(dtype).name, "ms_per_step": 1e3 * tm["run_s"] / n_steps,
                       "best_ms_per_step": 1e3 * tm["best_s"] / n_steps,
                       "steps_timed": n_steps, "compile_s": tm["compile_s"], "newton": float(jnp.mean(info.newton_iters)),
                       "cg_iters": float(jnp.mean(info.cg_iters)),
                       "converged": bool(jnp.all(info.converged)), "stable": bool(jnp.all(info.stable)), "error_vs_ref": err,
                       "speedup_vs_scipy": sp_row["ms_per_step"] / (1e3 * tm["run_s"] / n_steps)}
                rows.append(row)
                print(f"{name:22s} {label + ' ' + row['dtype']:34s} {row['ms_per_step']:9.3f} ms  err {err:.1e}  "
                      f"newton {row['newton']} cg {row['cg_iters']}  x{row['speedup_vs_scipy']:.1f} vs scipy  "
                      f"[{time.perf_counter() - T0:.0f} s]", flush=True)
        # written after every scene, so an interrupted run keeps what it measured
        write("cloth_step", {"rows": rows, "quick": args.quick, "complete": False})
    wall = time.perf_counter() - T0
    contact = contact_rows()
    write("cloth_step", {"rows": rows, "quick": args.quick, "complete": True, "wall_s_without_contact": wall,
                         "wall_s": time.perf_counter() - T0, "contact": contact})


if __name__ == "__main__":
    main()
