"""``python -m jaxsim demo``: the lab's two scenes on their embedded defaults, with pictures."""

from __future__ import annotations

import os
import time

from .._jobs.scenes import humanoid_targets
from ._timing import timed
from .demo_anim import anim_section
from .demo_cape import cape_section
from .demo_contact import contact_section
from .demo_pile import pile_section


def _ik_section(out: str, fast: bool, lines: list[str]) -> None:
    import numpy as np

    from .. import curves, ik, viz

    chain = ik.lab_arm()
    lines += ["## IK: the lab arm tracing curves (warm-started frame to frame, tol 1e-4)", "",
              "| curve | solver | frames | mean iters | max iters | max error (m) | all converged | ms/frame | files |",
              "|---|---|---|---|---|---|---|---|---|"]
    jobs = [(name, "fabrik") for name in curves.CURVES] + [("circle", "ccd")]
    for k, (name, solver) in enumerate(jobs, 1):
        targets = curves.CURVES[name]()
        print(f"[demo] IK {k}/{len(jobs)}: {name} ({len(targets)} points) with {solver} ...", flush=True)
        res, _, run_s = timed(lambda: ik.track(chain, targets[:, None], solver=solver))
        stem = f"ik_{name}" + ("" if solver == "fabrik" else f"_{solver}")
        title = f"{name}, {solver}"
        viz.save(viz.plot_tracking(res, targets, title=title), os.path.join(out, stem + ".png"))
        stride = 10 if fast else (4 if len(targets) > 200 else 2)
        viz.animate_tracking(res, targets, os.path.join(out, stem + ".gif"), stride=stride, title=title, plane="3d",
                             fps=15)
        it = np.asarray(res.iterations)
        lines.append(f"| {name} | {solver} | {len(targets)} | {it.mean():.2f} | {it.max()} | "
                     f"{float(np.max(res.error)):.2e} | {bool(np.all(res.converged))} | "
                     f"{1e3 * run_s / len(targets):.3f} | {stem}.gif, {stem}.png |")
    lines.append("")


def _humanoid_section(out: str, fast: bool, lines: list[str]) -> None:
    import numpy as np

    from .. import ik, viz

    H = ik.humanoid(limits=False)
    eff = tuple(H.index(n) for n in ik.HUMANOID_EFFECTORS)
    targets = humanoid_targets(H)
    print(f"[demo] humanoid: hands trace circle and heart, feet planted ({len(targets)} frames) ...", flush=True)
    res, _, run_s = timed(lambda: ik.track(H, targets, solver=ik.FABRIK(tol=1e-4), effectors=eff))
    viz.animate_skeleton(H, res.positions, os.path.join(out, "humanoid.gif"), effectors=eff, targets=targets,
                         stride=10 if fast else 2, title="humanoid, FABRIK")
    it = np.asarray(res.iterations)
    lines += ["## IK: the humanoid, hands on two curves, feet planted (FABRIK on the tree)", "",
              "| frames | mean sweeps | max error (m) | all converged | ms/frame | file |", "|---|---|---|---|---|---|",
              f"| {len(targets)} | {it.mean():.2f} | {float(np.max(res.error)):.2e} | {bool(np.all(res.converged))} | "
              f"{1e3 * run_s / len(targets):.3f} | humanoid.gif |", ""]


def _limits_section(out: str, fast: bool, lines: list[str]) -> None:
    """``humanoid_limits.gif``: the same hand trajectories, limits off (left, FABRIK) and on
    (right, Levenberg-Marquardt: the solver for limited rigs; FABRIK's projections stall
    against the limits)."""
    import numpy as np

    from .. import ik, viz

    H = ik.humanoid()
    eff = tuple(H.index(n) for n in ik.HUMANOID_EFFECTORS)
    targets = humanoid_targets(H)
    print(f"[demo] humanoid with joint limits, off and on ({len(targets)} frames) ...", flush=True)
    runs = (("off", "FABRIK", ik.humanoid(limits=False), ik.FABRIK(tol=1e-4)),
            ("on", "LM", H, ik.LevenbergMarquardt(tol=1e-4)))
    results = [ik.track(sk, targets, solver=solver, effectors=eff) for _, _, sk, solver in runs]
    shift = np.array([1.1, 0.0, 0.7])  # apart in both views: x (front) and z (side)
    P = np.concatenate([np.asarray(results[0].positions) - shift, np.asarray(results[1].positions) + shift], axis=1)
    T = np.concatenate([targets - shift, targets + shift], axis=1)
    J = H.num_joints
    parents = H.parents + tuple(J if p < 0 else p + J for p in H.parents)  # two figures, one drawing
    viz.animate_skeleton(parents, P, os.path.join(out, "humanoid_limits.gif"), effectors=eff + tuple(e + J for e in eff),
                         targets=T, views=("front", "side"), stride=10 if fast else 2,
                         title="limits off (left, FABRIK) and on (right, LM); the side view shows the elbows")
    lines += ["## IK: the humanoid with joint limits off (FABRIK) and on (Levenberg-Marquardt)", "",
              "| limits | solver | mean iterations | max error (m) | frames converged | max limit violation (rad) | "
              "elbow angle range (°) | file |", "|---|---|---|---|---|---|---|---|"]
    for (name, solver, _, _), res in zip(runs, results):
        viol = float(np.max(np.asarray(ik.limit_violation(H, res.rotations))))
        q = np.asarray(res.rotations)[:, H.index("l_elbow")]
        ang = np.degrees(2 * np.arctan2(-q[:, 2] * np.sign(q[:, 0] + 1e-30), np.abs(q[:, 0])))  # about -y
        lines.append(f"| {name} | {solver} | {np.asarray(res.iterations).mean():.2f} | {float(np.max(res.error)):.2e} | "
                     f"{100 * float(np.mean(res.converged)):.0f}% | {viol:.1e} | {ang.min():.0f} to {ang.max():.0f} | "
                     "humanoid_limits.gif |")
    lines.append("")


def _cloth_section(out: str, fast: bool, lines: list[str]) -> None:
    import numpy as np

    from .. import cloth, viz

    c = cloth.lab_cloth()
    seconds = 1.0 if fast else 5.0
    steps = int(round(60 * seconds))
    integ = cloth.ImplicitEuler()
    solver = "dense" if isinstance(integ.linear(c.num_particles), cloth.Cholesky) else "cg"
    print(f"[demo] cloth: lab cloth, {seconds:g} s at 60 steps/s, implicit Euler ({solver}) ...", flush=True)
    s0 = cloth.State.at_rest(c)
    (states, infos), compile_s, run_s = timed(lambda: cloth.rollout(c, s0, 1 / 60, steps, integ), again=False)
    rep = cloth.energy_report(c, s0, states, infos)
    print("[demo] cloth: drawing cloth.gif ...", flush=True)
    xs = np.concatenate([np.asarray(s0.x)[None], np.asarray(states.x)])
    viz.animate_cloth(c, xs, os.path.join(out, "cloth.gif"), stride=10 if fast else 4, fps=15, title="lab cloth")
    viz.save(viz.plot_cloth(c, xs[-1], title=f"lab cloth after {seconds:g} s"), os.path.join(out, "cloth.png"))
    lines += ["## Cloth: the lab cloth hanging from its two pinned corners", "",
              "| steps | ms/step | compile (s) | mean Newton | mean CG | all converged | stable | energy start (J) | energy end (J) | files |",
              "|---|---|---|---|---|---|---|---|---|---|",
              f"| {steps} | {1e3 * run_s / steps:.3f} | {compile_s:.1f} | {float(np.mean(infos.newton_iters)):.2f} | "
              f"{float(np.mean(infos.cg_iters)):.1f} | {bool(np.all(infos.converged))} | {bool(rep.stable)} | "
              f"{float(rep.energy[0]):.3f} | {float(rep.energy[-1]):.3f} | cloth.gif, cloth.png |", ""]


def run(out: str = "jaxsim-demo", fast: bool = False, checkpoint=None) -> int:
    """Write the demo into ``out``; ``checkpoint()`` (if given) runs after each section,
    so the CLI's manifest lists each section's files as soon as they are written."""
    from .._jobs.progress import Stage

    t0 = time.perf_counter()
    os.makedirs(out, exist_ok=True)
    mode = "fast" if fast else "full"
    lines = ["# jaxsim demo summary", "", f"Mode: {mode}.", ""]
    path = os.path.join(out, "summary.md")
    sections = ((_ik_section, "IK on the lab arm"), (_humanoid_section, "the humanoid"),
                (_limits_section, "the humanoid with limits"), (_cloth_section, "the lab cloth"),
                (contact_section, "cloth with colliders"), (anim_section, "the CMU walk"),
                (cape_section, "a cape on the CMU walk"), (pile_section, "a strip piling onto itself"))
    for k, (section, what) in enumerate(sections, start=1):
        with Stage("[demo]", f"section {k}/{len(sections)}, {what}", key=f"demo {mode} {section.__name__}"):
            section(out, fast, lines)
        with open(path, "w") as f:  # row by row: the summary so far, after every section
            f.write("\n".join(lines + ([] if k == len(sections) else ["(running: more sections follow)"])) + "\n")
        if checkpoint is not None:
            checkpoint()
    lines.append(f"Total wall time: {time.perf_counter() - t0:.1f} s")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"[demo] wrote {os.path.abspath(out)}/ (summary.md, ik_*.gif, ik_*.png, humanoid.gif, cloth.gif, cloth.png, "
          "cloth_sphere.gif, cloth_floor.gif, anim_walk.gif, cape.gif, cloth_pile.gif)")
    return 0
