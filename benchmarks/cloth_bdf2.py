"""BDF2 and TR-BDF2 against backward Euler: error against run time, energy kept, cost per step.

Accuracy: two undamped cloths released horizontal under g = 9.8 and swinging for 1 s,
float64, default settings (``SWINGS``): one whose springs are resolved at every step size
(6x6, sqrt(k/m) = 10 rad/s) and one whose springs are not (16x16, 113 rad/s).  Each
integrator runs at dt = 1/30, 1/60, 1/120 and 1/240; the reference is TR-BDF2 at dt = 1/1920.
Per row: the largest position error at 1 s against the reference (m), the share of the
swing's energy left at 1 s (total energy above the reference's lowest potential), Newton
iterations per step, and ms of run time per simulated second (warm, compile apart): the
error-against-time front.

Cost: scenes A (the lab cloth, CG and Cholesky) and B (32x32 and 128x128 grids, CG) of
``cloth_ab.py``, and scene C 32x32 at k = 1e3 (no damping, dt = 1/30), float64, from a
moving state 10 backward-Euler steps in; backward Euler, BDF2 and TR-BDF2 with the same
settings alternated in one process, median of rounds and the median paired ratio to
backward Euler.

Contact: ``cloth_substeps.py``'s drape (a 0.5 kg cloth dropped onto a sphere over a floor,
friction 0.4, k = 1e3, dt = 1/60, 60 steps from rest, float64, default settings) at 16x16
and 32x32: converged steps, substeps, the closest approach to a collider, the highest
total energy against the start's, and ms per step, the three alternated.

Run: ``python benchmarks/cloth_bdf2.py [--quick] [--only-contact]``; writes ``benchmarks/results/cloth_bdf2.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import time_call, write  # noqa: E402

import jaxsim  # noqa: E402
from jaxsim import cloth as C  # noqa: E402

INTEGRATORS = {"backward Euler": C.ImplicitEuler(), "BDF2": C.BDF2(), "TR-BDF2": C.TRBDF2()}


SWINGS = {
    # 6x6 particles 0.2 m apart, 1 kg each, k = 100, two corners pinned: the springs'
    # frequency sqrt(k/m) = 10 rad/s, resolved at every dt (h omega <= 0.33)
    "resolved 6x6": lambda: C.grid(5, 0.2, stiffness=100.0, damping=0.0, gravity=9.8, dtype=np.float64),
    # 16x16 particles 0.1 m apart, 1 kg in all, k = 50, pinned at one corner: sqrt(k/m) = 113 rad/s,
    # under-resolved at every dt here (h omega = 3.8 at 1/30)
    "stiff 16x16": lambda: C.grid(15, 0.1, mass=1.0 / 256, stiffness=50.0, damping=0.0, gravity=9.8, pins=[0],
                                  dtype=np.float64),
}


def energies(cloth, states):
    """``(T,)`` total and ``(T,)`` potential energy (J) along ``states``."""
    tot = jax.vmap(lambda x, v: C.total_energy(cloth, x, v))(states.x, states.v)
    return np.asarray(tot), np.asarray(jax.vmap(lambda x: C.energy(cloth, x))(states.x))


def accuracy(name, dts, t_end=1.0, ref_dt=1 / 1920):
    cloth = SWINGS[name]()
    s0 = C.State.at_rest(cloth)
    ref_states, ref_info = C.rollout(cloth, s0, ref_dt, int(round(t_end / ref_dt)), C.TRBDF2())
    e_ref, u_ref = energies(cloth, ref_states)
    e0 = float(C.total_energy(cloth, s0.x, s0.v))
    low = float(u_ref.min())  # the lowest potential the reference reaches: the swing's energy is e0 - low
    ref_x = np.asarray(ref_states.x[-1])
    print(f"{name} reference: TR-BDF2 dt=1/{round(1 / ref_dt)}, converged {100 * float(np.mean(ref_info.converged)):.0f}%, "
          f"energy drift {e_ref[-1] - e0:.2e} J of a swing of {e0 - low:.3f} J", flush=True)
    rows = []
    for dt in dts:
        n = int(round(t_end / dt))
        for integ_name, integ in INTEGRATORS.items():
            f = jax.jit(lambda s, integ=integ, dt=dt, n=n: C.rollout(cloth, s, dt, n, integ))
            t = time_call(f, s0, repeats=3)
            states, info = f(s0)
            e, _ = energies(cloth, states)
            row = {"scene": name, "integrator": integ_name, "dt": dt, "steps": n,
                   "error_m": float(np.abs(np.asarray(states.x[-1]) - ref_x).max()),
                   "energy_kept": float((e[-1] - low) / (e0 - low)), "energy_kept_ref": float((e_ref[-1] - low) / (e0 - low)),
                   "converged_share": float(np.mean(info.converged)),
                   "newton_per_step": float(np.mean(info.newton_iters)), "ms_per_sim_s": 1e3 * t["run_s"] / t_end,
                   "compile_s": t["compile_s"]}
            print(f"{name} {integ_name:14s} dt=1/{round(1 / dt)}: error {row['error_m']:.2e} m, energy kept "
                  f"{100 * row['energy_kept']:.1f}%, Newton {row['newton_per_step']:.2f}/step, "
                  f"{row['ms_per_sim_s']:.1f} ms per simulated s", flush=True)
            rows.append(row)
    return rows


def cost_cases(quick):
    """``(name, scene, linear solver, dt, steps)``: scenes A and B of ``cloth_ab.py`` and C."""
    out = [("A lab CG", C.lab_cloth(np.float64), C.CG(), 1 / 60, 10),
           ("A lab Cholesky", C.lab_cloth(np.float64), C.Cholesky(), 1 / 60, 10),
           ("B 32x32 CG", C.grid(31, 0.2, dtype=np.float64), C.CG(), 1 / 60, 10)]
    if not quick:
        out.append(("B 128x128 CG", C.grid(127, 0.2, dtype=np.float64), C.CG(), 1 / 60, 5))
    out.append(("C 32x32 k=1e3", C.grid(31, 0.2, mass=1.0 / 32**2, stiffness=1e3, gravity=9.8, damping=0.0,
                                        dtype=np.float64), C.Auto(), 1 / 30, 20))
    return out


def cost(quick, rounds):
    """ms per step of the integrators with the same settings, alternated in one
    process, from a moving state (10 backward-Euler steps in)."""
    rows = []
    for case, cloth, lin, dt, steps in cost_cases(quick):
        integs = {name: dataclasses.replace(integ, linear_solver=lin) for name, integ in INTEGRATORS.items()}
        warm, _ = C.rollout(cloth, C.State.at_rest(cloth), dt, 10, integs["backward Euler"])
        s0 = C.State(warm.x[-1], warm.v[-1])
        fns = {name: jax.jit(lambda s, integ=integ: C.rollout(cloth, s, dt, steps, integ)) for name, integ in integs.items()}
        compile_s = {name: time_call(f, s0, repeats=1)["compile_s"] for name, f in fns.items()}
        runs = {name: [] for name in fns}
        for _ in range(rounds):  # alternated, so both see the same machine load
            for name, f in fns.items():
                runs[name].append(time_call(f, s0, repeats=1)["run_s"])
        ratios = {name: [b / e for b, e in zip(runs[name], runs["backward Euler"])] for name in runs}
        for name, f in fns.items():
            _, info = f(s0)
            row = {"case": case, "integrator": name, "steps": steps, "dt": dt,
                   "ms_per_step": 1e3 * statistics.median(runs[name]) / steps,
                   "newton_per_step": float(np.mean(info.newton_iters)),
                   "substeps_total": int(jnp.sum(info.substeps)), "converged_share": float(np.mean(info.converged)),
                   "compile_s": compile_s[name]}
            if name != "backward Euler":
                row["paired_ratio_median"] = statistics.median(ratios[name])
            print(f"{case} {name:14s}: {row['ms_per_step']:.2f} ms/step, Newton {row['newton_per_step']:.2f}/step, "
                  f"substeps {row['substeps_total']}, converged {100 * row['converged_share']:.0f}%"
                  + (f", /BE paired {row['paired_ratio_median']:.2f}" if "paired_ratio_median" in row else ""), flush=True)
            rows.append(row)
    return rows


def contact(quick, rounds):
    """The drape under each integrator (module doc), alternated in one process."""
    from cloth_substeps import drape

    rows = []
    for n in (16,) if quick else (16, 32):
        cloth = drape(n, np.float64)
        s0 = C.State.at_rest(cloth)
        fns = {name: jax.jit(lambda s, integ=integ: C.rollout(cloth, s, 1 / 60, 60, integ))
               for name, integ in INTEGRATORS.items()}
        compile_s = {name: time_call(f, s0, repeats=1)["compile_s"] for name, f in fns.items()}
        runs = {name: [] for name in fns}
        for _ in range(rounds):
            for name, f in fns.items():
                runs[name].append(time_call(f, s0, repeats=1)["run_s"])
        e0 = float(C.total_energy(cloth, s0.x, s0.v))
        for name, f in fns.items():
            states, info = f(s0)
            gap = min(float(jnp.min(c.distance(states.x.reshape(-1, 3)))) for c in cloth.colliders)
            e = jax.vmap(lambda x, v: C.total_energy(cloth, x, v))(states.x, states.v)
            row = {"case": f"drape {n}x{n}", "integrator": name, "steps": 60, "dt": 1 / 60,
                   "ms_per_step": 1e3 * statistics.median(runs[name]) / 60,
                   "converged_share": float(np.mean(info.converged)), "substeps_total": int(jnp.sum(info.substeps)),
                   "newton_per_step": float(np.mean(info.newton_iters)), "min_distance_m": gap,
                   "energy_max_minus_start_J": float(jnp.max(e)) - e0, "compile_s": compile_s[name]}
            print(f"drape {n}x{n} {name:14s}: {row['ms_per_step']:.1f} ms/step, converged "
                  f"{100 * row['converged_share']:.0f}%, substeps {row['substeps_total']}, Newton "
                  f"{row['newton_per_step']:.2f}/step, min distance {gap:.2e} m, "
                  f"energy rise {row['energy_max_minus_start_J']:.2e} J", flush=True)
            rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer step sizes, no 128x128")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--only-contact", action="store_true", help="the drape rows only (merged into the last results)")
    args = ap.parse_args()
    jaxsim.retain_host_memory()
    if args.only_contact:
        import json

        path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "cloth_bdf2.json")
        with open(path) as f:
            last = json.load(f)
        kept = {k: v for k, v in last.items() if k not in ("benchmark", "machine", "timestamp", "contact")}
        kept["accuracy_and_cost_from"] = last.get("accuracy_and_cost_from", last.get("timestamp"))
        write("cloth_bdf2", dict(kept, contact=contact(args.quick, args.rounds)))
        return
    dts = (1 / 30, 1 / 60) if args.quick else (1 / 30, 1 / 60, 1 / 120, 1 / 240)
    acc = [r for name in SWINGS for r in accuracy(name, dts)]
    write("cloth_bdf2", {"accuracy": acc, "cost": cost(args.quick, args.rounds), "contact": contact(args.quick, args.rounds),
                         "swings": "released horizontal from rest, no damping, g 9.8, 1 s, float64, default settings; "
                                   "reference TR-BDF2 at dt 1/1920; resolved 6x6: 0.2 m apart, 1 kg each, k 100, two "
                                   "corners pinned; stiff 16x16: 0.1 m apart, 1 kg in all, k 50, one corner pinned; "
                                   "energy kept: (E(1 s) - U_min) / (E(0) - U_min), U_min the reference's lowest potential",
                         "cost_scenes": "A: the lab cloth; B: grid(n-1, 0.2) defaults; C: 32x32, 1 kg, k 1e3, g 9.8, "
                                        "no damping; float64, from 10 backward-Euler steps in; backward Euler, "
                                        "BDF2 and TR-BDF2 alternated, median of rounds, paired ratio to backward Euler"})


if __name__ == "__main__":
    main()
