"""The performance guide's tables, generated from ``benchmarks/results/*.json``.

``docs/performance.md`` and ``README.md`` hold each table between ``<!-- generated: NAME -->`` and
``<!-- end generated -->``.  ``python benchmarks/_tables.py`` prints them;
``--write`` rewrites those blocks in the guide from the JSON; ``--check`` exits 1 naming
the blocks that differ from it (``tests/test_doc_tables.py`` runs the check).
"""

from __future__ import annotations

import json
import os
import re
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
        if r["solver"].startswith(("humanoid", "hinge chain")):
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
    t = s["targets"]
    got = (s["fabrik_10_sweeps_solves_per_s"], s["ccd_10_sweeps_solves_per_s"], s["fabrik_speedup_vs_numpy"])
    met = [g >= w for g, w in zip(got, (t["fabrik_10"], t["ccd_10"], t["vs_numpy"]))]
    out += ["", f"Targets: {t['fabrik_10'] / 1e6:g} M solves/s for FABRIK at 10 sweeps, {t['ccd_10'] / 1e6:g} M/s for "
            f"CCD, and {t['vs_numpy']:g}x the numpy baseline.  This run ({d['timestamp'][:10]}) measured "
            f"{got[0] / 1e6:.2f} M/s ({'met' if met[0] else 'missed'}), {got[1] / 1e6:.2f} M/s "
            f"({'met' if met[1] else 'missed'}) and {got[2]:.1f}x ({'met' if met[2] else 'missed'})."]
    hum = [r for r in d["rows"] if r["solver"] in ("humanoid fabrik", "humanoid ccd")]
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


def substeps_table():
    d = load("cloth_substeps")
    out = ["| scene | dtype | max_substep_depth | converged | substeps (total / most in a step) | Newton/step | ms/step | compile (s) |",
           "|---|---|---|---|---|---|---|---|"]
    for r in d["rows"]:
        out.append(f"| {r['case']} | {r['dtype']} | {r['max_substep_depth']} | {100 * r['converged_share']:.1f}% | "
                   f"{r['substeps_total']} / {r['substeps_max']} ({r['steps']} steps) | {r['newton_per_step']:.1f} | "
                   f"{r['ms_per_step']:.1f} | {r['compile_s']:.1f} |")
    return "\n".join(out)


def _fall(r):
    return f"{r['fall']:.2f}" if "fall" in r else ""


def self_contact_table():
    out = ["| layers | solver | dtype | self-contact | converged | substeps (most) | Newton/step | ms/step | cost | "
           "compile (s) | frames intersecting | least gap (mm) | fall |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in ("cloth_self_contact_quick", "cloth_self_contact"):
        if not os.path.exists(os.path.join(RESULTS, name + ".json")):
            continue
        for r in load(name)["rows"]:
            head = f"| 2 x {r['n']}x{r['n']}, {r['steps']} steps "
            if r.get("solver") == "newton VBD":
                stable = "" if r["stable"] else " (unstable)"
                out.append(f"{head}| newton VBD{stable} | {r['dtype']} | on | | {r['substeps_per_frame']} a frame | | "
                           f"{r['ms_per_step']:.0f} | | {r['compile_s']:.1f} | {r['frames_intersecting']} | | "
                           f"{_fall(r)} |")
                continue
            cost = f"{r['cost_ratio']:.1f}x" if "cost_ratio" in r else "1"
            solver = "jaxsim" if r.get("newton_iters") is None else f"jaxsim, newton_iters={r['newton_iters']}"
            out.append(f"{head}| {solver} | {r['dtype']} | {'on' if r['self_contact'] else 'off'} | "
                       f"{100 * r['converged_share']:.1f}% | {r['substeps_max']} | {r['newton_per_step']:.1f} | "
                       f"{r['ms_per_step']:.0f} | {cost} | {r['compile_s']:.1f} | {r['frames_intersecting']} | "
                       f"{1e3 * r['least_layer_gap_m']:.2f} | {_fall(r)} |")
    return "\n".join(out)


def character_table():
    out = ["| cape | dtype | wind | steps | converged | substeps (most) | Newton/step | ms/step | compile (s) | "
           "min distance to body (mm) | pins off path (m) |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in ("cloth_character_quick", "cloth_character"):
        if not os.path.exists(os.path.join(RESULTS, name + ".json")):
            continue
        d = load(name)
        for r in d["rows"]:
            out.append(f"| {r['n']}x{r['n']}, {r['seconds']:g} s | {r['dtype']} | {'on' if r['wind'] else 'off'} | "
                       f"{r['steps']} | {100 * r['converged_share']:.1f}% | {r['substeps_max']} | "
                       f"{r['newton_per_step']:.1f} | {r['ms_per_step']:.0f} | {r['compile_s']:.1f} | "
                       f"{1e3 * r['min_distance_to_body_m']:.3f} | {r['max_pin_error_m']:.0e} |")
    out.append("")
    out.append(f"(`{'`, `'.join(n + '.json' for n in ('cloth_character_quick', 'cloth_character'))}`, "
               f"{load('cloth_character_quick')['timestamp'][:10]})")
    return "\n".join(out)


def bdf2_table():
    d = load("cloth_bdf2")
    out = ["| swing | integrator | dt | error at 1 s (m) | energy kept | Newton/step | ms per simulated s | compile (s) |",
           "|---|---|---|---|---|---|---|---|"]
    for r in d["accuracy"]:
        out.append(f"| {r['scene']} | {r['integrator']} | 1/{round(1 / r['dt'])} | {r['error_m']:.2e} | {100 * r['energy_kept']:.1f}% | "
                   f"{r['newton_per_step']:.2f} | {r['ms_per_sim_s']:.1f} | {r['compile_s']:.1f} |")
    out += ["", "| scene | integrator | ms/step | / backward Euler (paired) | Newton/step | substeps | converged | compile (s) |",
            "|---|---|---|---|---|---|---|---|"]
    for r in d["cost"]:
        ratio = f"{r['paired_ratio_median']:.2f}" if "paired_ratio_median" in r else ""
        out.append(f"| {r['case']} | {r['integrator']} | {r['ms_per_step']:.2f} | {ratio} | {r['newton_per_step']:.2f} | "
                   f"{r['substeps_total']} ({r['steps']} steps) | {100 * r['converged_share']:.0f}% | {r['compile_s']:.1f} |")
    if d.get("contact"):
        out += ["", "| drape | integrator | ms/step | converged | substeps | Newton/step | closest approach (m) | "
                "energy rise (J) | compile (s) |", "|---|---|---|---|---|---|---|---|---|"]
        for r in d["contact"]:
            out.append(f"| {r['case']} | {r['integrator']} | {r['ms_per_step']:.1f} | {100 * r['converged_share']:.0f}% | "
                       f"{r['substeps_total']} ({r['steps']} steps) | {r['newton_per_step']:.2f} | "
                       f"{r['min_distance_m']:.1e} | {r['energy_max_minus_start_J']:.1e} | {r['compile_s']:.1f} |")
    return "\n".join(out)


def friction_eps_table():
    d = load("cloth_friction_eps")
    out = ["| drape (float32) | max_substep_depth | float32 `eps_v` (m/s) | converged | substeps | Newton/step | "
           "ms/step | closest approach (m) |", "|---|---|---|---|---|---|---|---|"]
    for r in d["rows"]:
        out.append(f"| {r['n']}x{r['n']} | {r['max_substep_depth']} | {r['eps_v']:g} | {100 * r['converged_share']:.1f}% | "
                   f"{r['substeps_total']} (60 steps) | {r['newton_per_step']:.1f} | {r['ms_per_step']:.1f} | "
                   f"{r['closest_m']:.1e} |")
    return "\n".join(out)


def vbd_table():
    d = load("cloth_vbd")
    out = ["| drape | solver | dtype | substeps/frame | wall s per simulated s | CPU s per simulated s | stable | "
           "closest approach (m) | converged |", "|---|---|---|---|---|---|---|---|---|"]
    for r in d["rows"]:
        conv = f"{100 * r['converged_share']:.0f}%" if "converged_share" in r else ""
        out.append(f"| {r['n']}x{r['n']} | {r['solver']} | {r['dtype']} | {r['substeps_per_frame']} | "
                   f"{r['wall_s_per_sim_s']:.2f} | {r['cpu_s_per_sim_s']:.2f} | {'yes' if r['stable'] else 'no'} | "
                   f"{r['closest_m']:.1e} | {conv} |")
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


def headline_table():
    """The README's headline numbers."""
    ik, cl = load("ik_throughput"), load("cloth_step")
    s = ik["summary"]

    def step(scene, method, dtype="float64"):
        return next(r for r in cl["rows"] if r["scene"] == scene and r["method"] == method and r.get("dtype", dtype) == dtype)

    lab, big, scipy = (step("A lab 11x11", "cg converged default forcing"), step("B 128x128", "cg converged default forcing"),
                       step("B 128x128", "scipy spsolve Newton (tol 1e-6)"))
    stiff = step("C 32x32 k=1e+05", "cg converged default forcing two-level")
    ikpy = f", {s['fabrik_speedup_vs_ikpy']:,.0f}× ikpy" if s.get("fabrik_speedup_vs_ikpy") else ""
    rows = [("chain FABRIK, 10 sweeps, float32, batched", f"{s['fabrik_10_sweeps_solves_per_s'] / 1e6:.2f} M solves/s "
             f"({s['fabrik_speedup_vs_numpy']:.0f}× a vectorised numpy FABRIK{ikpy})", "ik_throughput"),
            ("chain CCD, 10 sweeps", f"{s['ccd_10_sweeps_solves_per_s'] / 1e6:.2f} M solves/s", "ik_throughput"),
            ("humanoid (24 joints, 4 effectors) FABRIK, 10 sweeps",
             f"{s['humanoid']['fabrik_10_sweeps']['solves_per_s']:,.0f} sets/s", "ik_throughput"),
            ("lab cloth (11×11) implicit step, float64", f"{lab['ms_per_step']:.3f} ms", "cloth_step"),
            (f"128×128-particle cloth implicit step, float64 (scipy sparse Newton: {scipy['ms_per_step'] / 1e3:.2f} s)",
             f"{big['ms_per_step']:.2f} ms", "cloth_step"),
            ("stiff 32×32-particle cloth (k = 1e5) implicit step",
             f"{stiff['ms_per_step']:.1f} ms" + (", every timed step converged" if stiff["converged"] else
                                                  ", not every timed step converged"), "cloth_step")]
    return "\n".join(["| what | number | source |", "|---|---|---|"]
                     + [f"| {a} | {b} | `{c}.json` ({load(c)['timestamp'][:10]}) |" for a, b, c in rows])


TABLES = {"vbd": vbd_table, "headline": headline_table, "ik": ik_table, "stability": stability_table, "cloth": cloth_table, "scaling": scaling_table,
          "substeps": substeps_table, "bdf2": bdf2_table, "friction_eps": friction_eps_table,
          "self_contact": self_contact_table, "character": character_table}
_ROOT = os.path.join(os.path.dirname(RESULTS), os.pardir)
GUIDES = (os.path.join(_ROOT, "docs", "performance.md"), os.path.join(_ROOT, "README.md"),
          os.path.join(_ROOT, "docs", "character.md"))
_BLOCK = re.compile(r"(<!-- generated: (\w+) -->\n)(.*?)(<!-- end generated -->)", re.S)


def render(text: str) -> str:
    """``text`` with every generated block replaced by its table from the JSON."""
    return _BLOCK.sub(lambda m: m.group(1) + TABLES[m.group(2)]().rstrip() + "\n" + m.group(4), text)


def blocks(path: str) -> list:
    """Names of the generated blocks in ``path``."""
    with open(path, encoding="utf-8") as f:
        return [m.group(2) for m in _BLOCK.finditer(f.read())]


def stale(paths=GUIDES) -> list:
    """Names of the generated blocks in ``paths`` that differ from the JSON."""
    out = []
    for path in [paths] if isinstance(paths, str) else paths:
        with open(path, encoding="utf-8") as f:
            text = f.read()
        out += [m.group(2) for m in _BLOCK.finditer(text) if m.group(3).rstrip() != TABLES[m.group(2)]().rstrip()]
    return out


def main(argv):
    if "--check" in argv:
        bad = stale()
        print("stale generated tables: " + ", ".join(bad) if bad else "generated tables are up to date")
        return 1 if bad else 0
    if "--write" in argv:
        for path in GUIDES:
            with open(path, encoding="utf-8") as f:
                text = f.read()
            with open(path, "w", encoding="utf-8") as f:
                f.write(render(text))
            print(f"rewrote the generated tables in {os.path.normpath(path)}")
        return 0
    for w in [a for a in argv if not a.startswith("--")] or list(TABLES):
        print(TABLES[w]())
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
