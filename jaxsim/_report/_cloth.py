"""Cloth sections of the report: error against run time, stability maps, stress
table, and cost growth with the particle count."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from .. import cloth as C
from ._doc import Doc, fig_axes


def _time_rollout(c, s, dt, n, integ):
    """Compile apart; return ``((states, infos), seconds per step)`` of a warm run."""
    jax.block_until_ready(C.rollout(c, s, dt, n, integ))
    t0 = time.perf_counter()
    out = jax.block_until_ready(C.rollout(c, s, dt, n, integ))
    return out, (time.perf_counter() - t0) / n


def _last(states):
    return C.State(states.x[-1], states.v[-1])


def pareto(doc: Doc) -> None:
    from matplotlib.ticker import NullFormatter

    quick = doc.quick
    scenes = {"lab cloth 11x11": C.lab_cloth()}
    if not quick:  # quick mode: the lab cloth only
        scenes["32x32 grid"] = C.grid(31, 0.2)
    # quick mode: 0.5 s, so the hang and the default CG method are one compiled program
    dt, T = 1 / 60, (30 if quick else 60)
    horizon = f"{T * dt:g} s"
    subs = (1, 100) if quick else (1, 3, 10, 30, 100, 300, 1000)
    cg_tols = (1e-6,) if quick else (1e-2, 1e-4, 1e-6, 1e-8)
    ref_subs = 500 if quick else 4000
    doc.md("## Cloth 1. Error against run time per step",
           f"Each scene first hangs for 0.5 s (30 converged implicit steps); from that moving state every method runs "
           f"{T} steps of dt = 1/60 s ({horizon}).  (a) **solver error**: max position error after one step against the "
           "exactly solved backward-Euler step (Newton to 1e-12 with CG to 1e-12).  (b) **physical error**: max position "
           f"error at t = {horizon} against a reference trajectory of symplectic Euler with {ref_subs} substeps per frame "
           f"(dt/{ref_subs}); the reference's own error is estimated against one with half as many substeps.  "
           "Run time: median warm `rollout` time per step, compile excluded.  float64.")
    rows = []
    fig, axes = fig_axes(len(scenes), 2, w=4.6, h=3.4)
    for col, (name, c) in enumerate(scenes.items()):
        doc.progress(f"cloth 1/4: {name}: start state and reference ({ref_subs} substeps/frame)")
        s30 = _last(C.rollout(c, C.State.at_rest(c), dt, 30, C.ImplicitEuler(linear_solver=C.CG()))[0])
        exact1 = C.step(c, s30, dt, C.ImplicitEuler(linear_solver=C.CG(tol=1e-12), tol=1e-12, newton_iters=50))[0]
        ref = _last(C.rollout(c, s30, dt, T, C.ExplicitEuler(substeps=ref_subs))[0])
        ref_half = _last(C.rollout(c, s30, dt, T, C.ExplicitEuler(substeps=ref_subs // 2))[0])
        ref_err = float(jnp.max(jnp.abs(ref.x - ref_half.x)))
        methods = [(f"explicit x{s}", "explicit", C.ExplicitEuler(substeps=s)) for s in subs]
        lab_step = C.ImplicitEuler(linear_solver=C.CG(), newton_iters=1, line_search=False, extrapolate=False)  # linearised at x^n
        methods += [("implicit one-Newton", "one-Newton", lab_step)]
        if not quick:  # quick mode: no dense solve (its compile dominates the quick run)
            methods += [("implicit dense, converged", "dense", C.ImplicitEuler(linear_solver=C.Cholesky()))]
        methods += [(f"implicit CG tol {t:.0e}", "CG", C.ImplicitEuler(linear_solver=C.CG(tol=t))) for t in cg_tols]
        methods += [(f"BDF2 CG tol {t:.0e}", "BDF2", C.BDF2(linear_solver=C.CG(tol=t))) for t in cg_tols[-2:]]
        for k, (label, family, integ) in enumerate(methods):
            doc.progress(f"cloth 1/4: {name}: {label} ({k + 1}/{len(methods)})")
            (states, infos), sec = _time_rollout(c, s30, dt, T, integ)
            one = C.State(states.x[0], states.v[0])  # the first step from s30
            stable = bool(jnp.all(infos.stable))
            rows.append({"scene": name, "method": label, "family": family, "ms": 1e3 * sec,
                         "solver_err": float(jnp.max(jnp.abs(one.x - exact1.x))) if family != "explicit" else np.nan,
                         "phys_err": float(jnp.max(jnp.abs(states.x[-1] - ref.x))) if stable else np.inf,
                         "stable": stable, "ref_err": ref_err})
        for r_, key, ax in ((0, "phys_err", axes[0, col]), (1, "solver_err", axes[1, col])):
            for fam, color in (("explicit", "C2"), ("one-Newton", "C1"), ("dense", "C4"), ("CG", "C0"), ("BDF2", "C3")):
                pts = [r for r in rows if r["scene"] == name and r["family"] == fam and np.isfinite(r[key])]
                if pts:
                    ax.loglog([p["ms"] for p in pts], [max(p[key], 1e-17) for p in pts], "-o", ms=4, color=color, label=fam)
                    for p in pts:
                        tag = p["method"].split()[-1] if fam in ("explicit", "CG", "BDF2") else ""
                        ax.annotate(tag, (p["ms"], max(p[key], 1e-17)), fontsize=5, xytext=(2, 2), textcoords="offset points")
            if key == "phys_err":
                ax.axhline(ref_err, color="0.5", ls=":", label="reference's own error")
            ax.set_title(f"{name}: {f'physical error at t = {horizon}' if key == 'phys_err' else 'solver error, one step'}", fontsize=8)
            ax.set_xlabel("run time per step (ms)")
            ax.set_ylabel("max position error (m)")
            ax.xaxis.set_minor_formatter(NullFormatter())  # a narrow log range labels its minor ticks on top of each other
            ax.legend(fontsize=6)
    fig.tight_layout()
    doc.figure(fig, "cloth_pareto.png", f"Cloth: error against run time per step (top: physical error over {horizon}; bottom: solver error of one step)")
    doc.table("cloth_pareto", rows, {"scene": "scene", "method": "method", "ms": "ms/step", "solver_err": "solver error (m)",
                                     "phys_err": f"physical error at {horizon} (m)", "stable": "stable"},
              {"ms": ".3f", "solver_err": lambda v: "" if not np.isfinite(v) else f"{v:.1e}",
               "phys_err": lambda v: "unstable" if not np.isfinite(v) else f"{v:.1e}"})
    text = []
    for name in scenes:
        rs = [r for r in rows if r["scene"] == name and np.isfinite(r["phys_err"])]
        best = min(rs, key=lambda r: r["phys_err"])
        cheap = min(rs, key=lambda r: r["ms"])
        ref_err = rs[0]["ref_err"]
        imp = [r for r in rs if r["family"] not in ("explicit", "BDF2")]
        spread = (max(r["phys_err"] for r in imp) / max(min(r["phys_err"] for r in imp), 1e-30)) if imp else np.nan
        text.append(f"*{name}*: the most accurate over {horizon} is {best['method']} ({best['phys_err']:.1e} m, "
                    f"{best['ms']:.2f} ms/step; reference error {ref_err:.1e} m); the cheapest stable one is {cheap['method']} "
                    f"({cheap['ms']:.3f} ms/step, {cheap['phys_err']:.1e} m).  All backward-Euler variants sit within a "
                    f"factor {spread:.1f} of each other in physical error: its own O(dt) damping dominates, so a "
                    "loose CG tolerance or a single Newton step costs little accuracy in motion while it cuts the time.")
        bdf = [r for r in rs if r["family"] == "BDF2"]
        be = [r for r in imp if r["family"] == "CG"]
        if bdf and be:
            b, e = min(bdf, key=lambda r: r["phys_err"]), min(be, key=lambda r: r["phys_err"])
            text.append(f"BDF2 ({b['method']}), second order on the same Newton solve, has {b['phys_err'] / e['phys_err']:.2f}x "
                        f"the physical error of backward Euler's best CG run ({b['phys_err']:.1e} against "
                        f"{e['phys_err']:.1e} m) at {b['ms'] / e['ms']:.2f}x its time per step.")
    doc.md("**Which wins where.**  " + "  ".join(text) + "  Explicit Euler wins when high accuracy is wanted and the "
           "scene is soft enough for few substeps; implicit Euler wins whenever the explicit step would need many "
           "substeps for stability (stiff springs, large dt, see the stability map), and for solver accuracy at fixed "
           "cost CG beats the dense solve on every scene but the smallest.")


def _omega_max_sq(c):
    """Largest eigenvalue of ``M^{-1} K`` at rest over free particles, for unit stiffness."""
    c1 = C.replace(c, stiffness=1.0)
    H, _ = C.reference.spring_hessian(c1, c1.rest)
    free = np.repeat(~np.asarray(c.pinned), 3)
    m = np.repeat(np.asarray(c.mass), 3)
    Hf = np.asarray(H)[np.ix_(free, free)] / np.sqrt(np.outer(m[free], m[free]))
    return float(np.linalg.eigvalsh(Hf)[-1])


def stability_map(doc: Doc) -> None:
    quick = doc.quick
    ks = (1e2, 1e4, 1e7) if quick else (1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7)
    dts = (1 / 1000, 1 / 30, 1 / 10) if quick else (1 / 1000, 1 / 300, 1 / 100, 1 / 30, 1 / 10)
    steps = 60 if quick else 100
    scenes = {"lab cloth 11x11": C.lab_cloth()}
    if not quick:  # quick mode: the lab cloth only
        scenes["24x24 grid"] = C.grid(23, 0.2)
    integs = {"explicit Euler (1 substep)": C.ExplicitEuler(substeps=1), "implicit Euler (Newton + line search)": C.ImplicitEuler(),
              "BDF2 (Newton + line search)": C.BDF2()}
    doc.md("## Cloth 2. Stability map",
           f"{steps} steps from rest for every stiffness k and time step dt.  **unstable**: a step was rejected "
           "(`StepInfo.stable` False: non-finite or flown off) ; **energy growth**: stable, but the total energy rose "
           "above its initial value by more than 0.1%; **stable**: neither.  The dashed line is explicit Euler's "
           "theoretical limit dt = 2/omega_max, omega_max^2 the largest eigenvalue of M^-1 K at rest (free particles).")
    fig, axes = fig_axes(len(integs), len(scenes), w=3.9, h=3.2)
    rows = []
    cmap = {"stable": 0, "energy growth": 1, "unstable": 2}
    for r_, (sname, c) in enumerate(scenes.items()):
        lam1 = _omega_max_sq(c)
        s0 = C.State.at_rest(c)
        for c_, (iname, integ) in enumerate(integs.items()):
            doc.progress(f"cloth 2/4: {sname}, {iname}: {len(ks) * len(dts)} runs")
            grid = np.zeros((len(ks), len(dts)))
            for a, k in enumerate(ks):
                ck = C.replace(c, stiffness=k)
                for b, dt in enumerate(dts):
                    states, infos = C.rollout(ck, s0, dt, steps, integ)
                    rep = C.energy_report(ck, s0, states, infos)
                    E = np.asarray(rep.energy)
                    if not (bool(rep.stable) and bool(rep.finite)):
                        cls = "unstable"
                    elif E.max() - E[0] > 1e-3 * max(abs(E[0]), 1e-9):
                        cls = "energy growth"
                    else:
                        cls = "stable"
                    grid[a, b] = cmap[cls]
                    rows.append({"scene": sname, "integrator": iname, "k": k, "dt": dt, "class": cls,
                                 "explicit_limit": 2 / np.sqrt(k * lam1)})
            ax = axes[r_, c_]
            from matplotlib.colors import ListedColormap

            ax.pcolormesh(np.arange(len(dts) + 1), np.arange(len(ks) + 1), grid, cmap=ListedColormap(["#4caf50", "#ffb300", "#e53935"]),
                          vmin=0, vmax=2, edgecolors="w", linewidth=0.5)
            # explicit limit, in cell coordinates (log-interpolated)
            ld = np.log10(np.asarray(dts))
            kk = np.logspace(np.log10(ks[0]), np.log10(ks[-1]), 100)
            lim = np.log10(2 / np.sqrt(kk * lam1))
            xs = np.interp(lim, ld, np.arange(len(dts)) + 0.5, left=np.nan, right=np.nan)
            ys = np.interp(np.log10(kk), np.log10(ks), np.arange(len(ks)) + 0.5)
            ax.plot(xs, ys, "k--", lw=1.2, label="explicit limit 2/omega_max")
            ax.set_xticks(np.arange(len(dts)) + 0.5)
            ax.set_xticklabels([f"1/{round(1 / d)}" for d in dts], fontsize=7)
            ax.set_yticks(np.arange(len(ks)) + 0.5)
            ax.set_yticklabels([f"{k:.0e}" for k in ks], fontsize=7)
            ax.set_xlabel("dt (s)")
            ax.set_ylabel("stiffness k (N/m)")
            ax.set_title(f"{sname}\n{iname}", fontsize=8)
            ax.legend(fontsize=6, loc="upper left")
    fig.tight_layout()
    doc.figure(fig, "cloth_stability_map.png", "Stability maps (green stable, amber energy growth, red unstable)")
    summary = []
    for sname in scenes:
        for iname in integs:
            rs = [r for r in rows if r["scene"] == sname and r["integrator"] == iname]
            summary.append({"scene": sname, "integrator": iname, "cells": len(rs),
                            "stable": sum(r["class"] == "stable" for r in rs),
                            "growth": sum(r["class"] == "energy growth" for r in rs),
                            "unstable": sum(r["class"] == "unstable" for r in rs)})
    doc.tables["cloth_stability_cells"] = rows
    doc.table("cloth_stability", summary, {"scene": "scene", "integrator": "integrator", "cells": "cells",
                                           "stable": "stable", "growth": "energy growth", "unstable": "unstable"})
    for sname in scenes:
        cell = {r["integrator"].split()[0]: r["class"] for r in rows
                if r["scene"] == sname and r["k"] == 1e4 and abs(r["dt"] - 1 / 30) < 1e-12}
        doc.md(f"{sname}, k = 1e4, dt = 1/30: explicit {cell['explicit']}, implicit {cell['implicit']}, BDF2 {cell['BDF2']}.")
    ex = [r for r in rows if r["integrator"].startswith("explicit") and r["scene"].startswith("lab")]
    agree = sum((r["class"] == "unstable") == (r["dt"] > r["explicit_limit"]) for r in ex)
    unstable = {i: sum(r["class"] == "unstable" for r in rows if r["integrator"] == i) for i in integs}
    growth = {i: sum(r["class"] == "energy growth" for r in rows if r["integrator"] == i) for i in integs}
    im, bd = "implicit Euler (Newton + line search)", "BDF2 (Newton + line search)"
    doc.md(f"On the lab cloth the explicit map agrees with the linear limit 2/omega_max in {agree} of {len(ex)} cells "
           "(the limit is computed at rest; a sagging, stretched cloth has slightly different frequencies).  Unstable "
           f"cells: implicit Euler {unstable[im]}, BDF2 {unstable[bd]} of {len(rows) // len(integs)}; energy growth: "
           f"implicit Euler {growth[im]}, BDF2 {growth[bd]} (BDF2 damps far less, so it keeps energy backward Euler "
           "takes away, and is not guaranteed to lose it).")


def stress(doc: Doc) -> None:
    steps = 10 if doc.quick else 100
    doc.md("## Cloth 3. Stress table",
           f"The lab cloth, {steps} steps of implicit Euler (auto solver, line search, PSD projection) in each precision.  "
           "'max energy rise' is the largest single-step increase of the total energy (kinetic + spring + gravity).")
    rows = []
    for dtype in (np.float64, np.float32):
        base = C.lab_cloth(dtype=dtype)
        rest = np.asarray(base.rest, np.float64)
        centre = rest.mean(0)
        cases = {
            "k = 1e7, dt = 1/60": (C.replace(base, stiffness=1e7), rest, 1 / 60),
            "dt = 1/10": (base, rest, 1 / 10),
            "k = 1e7, dt = 1/10": (C.replace(base, stiffness=1e7), rest, 1 / 10),
            "start stretched 3x": (base, centre + 3.0 * (rest - centre), 1 / 60),
            "start crushed 0.01x": (base, centre + 0.01 * (rest - centre), 1 / 60),
        }
        for name, (c, x0, dt) in cases.items():
            doc.progress(f"cloth 3/4: {name}, {np.dtype(dtype).name}")
            x0 = jnp.asarray(x0, dtype)
            x0 = jnp.where(jnp.asarray(c.pinned)[:, None], c.rest, x0)
            s0 = C.State(x0, jnp.zeros_like(x0))
            states, infos = C.rollout(c, s0, dt, steps, C.ImplicitEuler())
            rep = C.energy_report(c, s0, states, infos)
            rows.append({"case": name, "dtype": np.dtype(dtype).name, "finite": bool(rep.finite), "stable": bool(rep.stable),
                         "rise": float(rep.max_rise), "rises": int(rep.rises), "net": float(rep.net_change),
                         "newton": f"{float(jnp.mean(infos.newton_iters)):.1f} / {int(jnp.max(infos.newton_iters))}",
                         "cg": f"{float(jnp.mean(infos.cg_iters)):.0f} / {int(jnp.max(infos.cg_iters))}",
                         "bt": int(jnp.sum(infos.backtracks)), "conv": 100.0 * float(jnp.mean(infos.converged))})
    doc.table("cloth_stress", rows, {"case": "case", "dtype": "dtype", "finite": "finite", "stable": "stable",
                                     "rise": "max energy rise (J)", "rises": "steps with a rise", "net": "net energy change (J)",
                                     "newton": "Newton mean / max", "cg": "CG mean / max", "bt": "backtracks",
                                     "conv": "converged %"}, {"rise": ".2e", "net": ".3g", "conv": ".0f"})


def cost_growth(doc: Doc) -> None:
    quick = doc.quick
    sides = (8, 16) if quick else (8, 16, 32, 64, 128)
    dense_max = 16 if quick else 32
    doc.md("## Cloth 4. Cost growth",
           "Lab-like grids (m = 1, k = 100, spacing 0.2, d = 0.2, g = 0.3, two pinned corners, dt = 1/60), time per "
           "converged implicit step (default `ImplicitEuler`: the gradient test, CG tol 1e-6) from a state after 10 steps, median of a warm "
           f"10-step rollout, float64.  Dense up to {dense_max}x{dense_max} particles.")
    rows = []
    for n in sides:
        c = C.grid(n - 1, 0.2)
        s = _last(C.rollout(c, C.State.at_rest(c), 1 / 60, 10, C.ImplicitEuler(linear_solver=C.CG()))[0])
        for solver in ("dense", "cg"):
            if solver == "dense" and n > dense_max:
                continue
            doc.progress(f"cloth 4/4: {n}x{n}, {solver}")
            _, sec = _time_rollout(c, s, 1 / 60, 10,
                                   C.ImplicitEuler(linear_solver=C.Cholesky() if solver == "dense" else C.CG()))
            rows.append({"side": n, "N": n * n, "solver": solver, "ms": 1e3 * sec})
    fig, axes = fig_axes(1, 1, w=5.5, h=4.0)
    ax = axes[0, 0]
    fits = {}
    for solver, color in (("dense", "C4"), ("cg", "C0")):
        pts = [r for r in rows if r["solver"] == solver]
        N = np.array([p["N"] for p in pts], float)
        t = np.array([p["ms"] for p in pts])
        slope = np.polyfit(np.log(N), np.log(t), 1)[0] if len(pts) > 1 else np.nan
        fits[solver] = slope
        ax.loglog(N, t, "-o", color=color, label=f"{solver}: time ~ N^{slope:.2f}")
    # crossover: where the dense and CG curves cross (log-interpolated over shared sizes)
    shared = sorted({r["N"] for r in rows if r["solver"] == "dense"})
    ratio = [next(r["ms"] for r in rows if r["N"] == N and r["solver"] == "dense") /
             next(r["ms"] for r in rows if r["N"] == N and r["solver"] == "cg") for N in shared]
    cross = None
    for (N0, r0), (N1, r1) in zip(zip(shared, ratio), zip(shared[1:], ratio[1:])):
        if r0 <= 1 < r1:
            cross = float(np.exp(np.interp(0.0, [np.log(r0), np.log(r1)], [np.log(N0), np.log(N1)])))
    ax.axvline(C.AUTO_DENSE_MAX_PARTICLES, color="0.5", ls=":", label=f"auto switches at N = {C.AUTO_DENSE_MAX_PARTICLES}")
    ax.set_xlabel("particles N")
    ax.set_ylabel("time per converged step (ms)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    doc.figure(fig, "cloth_cost_growth.png", "Time per converged implicit step against particle count (log-log, fitted exponents)")
    doc.table("cloth_cost", rows, {"side": "grid", "N": "particles", "solver": "solver", "ms": "ms/step"}, {"ms": ".3f"})
    where = (f"the measured dense/CG crossover is near N = {cross:.0f}" if cross else
             f"dense is slower than CG at every measured size from N = {shared[0]} up (dense/CG time ratio "
             f"{ratio[0]:.1f} at the smallest), so the crossover lies below N = {shared[0]}")
    doc.facts.update({"dense_exponent": fits["dense"], "cg_exponent": fits["cg"]})
    doc.md(f"Fitted exponents: dense {fits['dense']:.2f}, CG {fits['cg']:.2f} (time ~ N^p).  {where}; "
           f"`solver=\"auto\"` uses dense up to N = {C.AUTO_DENSE_MAX_PARTICLES} particles and CG above.")


def run(doc: Doc) -> None:
    """Cloth 1 and 2: error against run time, and the stability map."""
    pareto(doc)
    stability_map(doc)


def run_stress_and_cost(doc: Doc) -> None:
    """Cloth 3 and 4: the stress table, and cost growth with the particle count."""
    stress(doc)
    cost_growth(doc)
