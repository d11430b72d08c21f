"""Print the README's markdown tables from ``benchmarks/results/*.json``."""

from __future__ import annotations

import json
import os
import sys

sys.path.insert(0, os.path.dirname(__file__))
from _common import RESULTS  # noqa: E402


def load(name):
    with open(os.path.join(RESULTS, name + ".json")) as f:
        return json.load(f)


def ik_table():
    d = load("ik_throughput")
    out = ["| solver | setting | layout | M solves/s | run (ms) | compile (s) | mean sweeps | HLO fusions |",
           "|---|---|---|---|---|---|---|---|"]
    for r in d["rows"]:
        if r["solver"].startswith("humanoid"):
            continue
        if r["solver"] == "ikpy":
            out.append(f"| ikpy | default | `inverse_kinematics`, one target | {r['solves_per_s'] / 1e6:.6f} | | | | |")
            continue
        layout = r["label"].split(r["mode"])[-1].strip() or r["label"].split(" ")[0] + ", vectorised over targets"
        comp = f"{r['compile_s']:.2f}" if "compile_s" in r else "–"
        its = f"{r['mean_iterations']:.1f}" if "mean_iterations" in r else "–"
        fus = str(r["hlo_fusions"]) if "hlo_fusions" in r else "–"
        out.append(f"| {r['solver']} | {r['mode']} | {layout} | {r['solves_per_s'] / 1e6:.3f} | "
                   f"{1e3 * r['run_s']:.1f} | {comp} | {its} | {fus} |")
    s = d["summary"]
    out += ["", f"FABRIK vs the numpy baseline: {s['fabrik_speedup_vs_numpy']:.1f}x; max |difference| to it on reachable "
            f"targets {s['max_abs_diff_vs_numpy_fabrik']:.1e}."]
    hum = [r for r in d["rows"] if r["solver"].startswith("humanoid")]
    if hum:
        out += ["", f"The humanoid, hands and ankles as effectors, {hum[0]['n']:,} float32 target sets (FK of random "
                "poses), from the rest pose:", "",
                "| solver | setting | sets/s | run (ms) | compile (s) | mean sweeps | converged % |", "|---|---|---|---|---|---|---|"]
        for r in hum:
            out.append(f"| {r['solver'].split()[1]} | {r['mode']}{' (early exit)' if 'tol' in r['mode'] else ''} | "
                       f"{r['solves_per_s']:,.0f} | {1e3 * r['run_s']:.1f} | {r['compile_s']:.1f} | "
                       f"{r['mean_iterations']:.1f} | "
                       + (f"{100 * r['converged_fraction']:.1f} |" if "tol" in r["mode"] else "– (tol 0) |"))
    return "\n".join(out)


def stability_table():
    d = load("cloth_stability")
    out = []
    for name, rows in d["scenes"].items():
        out += [f"**{name}**", "", "| k (N/m) | dt (s) | finite | E_end <= E0 | steps with rise | max rise (J) | Newton mean/max | CG max | backtracks | converged |",
                "|---|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            out.append(f"| {r['k']:.0e} | 1/{round(1 / r['dt'])} | {r['finite']} | {r['energy_not_above_initial']} | {r['rises']} | "
                       f"{r['max_rise']:.1e} | {r['mean_newton']:.1f}/{r['max_newton']} | {r['max_cg']} | {r['backtracks']} | "
                       f"{100 * r['converged_fraction']:.0f}% |")
        out.append("")
    return "\n".join(out)


def cloth_table():
    d = load("cloth_step")
    out = ["| scene | method | dtype | ms/step | Newton | CG | converged | max error vs ref (m) | speed-up vs scipy |",
           "|---|---|---|---|---|---|---|---|---|"]
    for r in d["rows"]:
        if r["method"].startswith("scipy"):
            out.append(f"| {r['scene']} | {r['method']} | float64 | {r['ms_per_step']:.2f} | {r['newton']} | | | "
                       f"{r['error_vs_ref']:.1e} | 1 |")
        else:
            out.append(f"| {r['scene']} | {r['method']} | {r['dtype']} | {r['ms_per_step']:.3f} | {r['newton']:.1f} | {r['cg_iters']:.1f} | "
                       f"{'yes' if r['converged'] else 'no'} | {r['error_vs_ref']:.1e} | {r['speedup_vs_scipy']:.1f} |")
    return "\n".join(out)


def scaling_table():
    d = load("scaling")
    out = ["| forced host devices | IK M solves/s (100k targets) | IK speed-up | IK weak-scaling efficiency | "
           "cloth scene-steps/s (8 scenes) | cloth speed-up | cloth weak-scaling efficiency |", "|---|---|---|---|---|---|---|"]
    for r in d["summary"]:
        out.append(f"| {r['devices']} | {r['ik_strong_M_per_s']:.2f} | {r['ik_strong_speedup']:.2f} | {r['ik_weak_efficiency']:.2f} | "
                   f"{r['cloth_strong_scene_steps_per_s']:.0f} | {r['cloth_strong_speedup']:.2f} | {r['cloth_weak_efficiency']:.2f} |")
    one = d["raw"][0]
    out += ["", f"One device, default `sharded=None` against `sharded=False` (the same code path, no placement): "
            f"IK {one['ik_strong']['run_s'] / one['ik_unsharded_baseline']['run_s']:.2f}x the time, cloth "
            f"{one['cloth_strong']['run_s'] / one['cloth_unsharded_baseline']['run_s']:.2f}x (run-to-run noise)."]
    return "\n".join(out)


if __name__ == "__main__":
    which = sys.argv[1:] or ["ik", "stability", "cloth", "scaling"]
    for w in which:
        print({"ik": ik_table, "stability": stability_table, "cloth": cloth_table, "scaling": scaling_table}[w]())
        print()
