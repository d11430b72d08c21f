"""PyRoki (the ``almond-pyroki`` package, bench extra) against our LM, same run, same sets.

Our humanoid written as a URDF: each ball joint as three revolute joints (x, y, z, so any
rotation is reachable), each hinge as one revolute joint with its range, the hands and toes
fixed.  Two problems, on 1,000 float32 target sets for hands and ankles made by FK of random
poses: the free humanoid, and the humanoid with only its hinges (elbows, knees) limited,
since a URDF has no swing-twist cone.  PyRoki: one Levenberg-Marquardt solve per set through
jaxls (dense Cholesky, at most 100 iterations, its default termination), the four position
costs (orientation weight 0) and, with limits, its limit cost at weight 100; batched with
``lax.map`` (``vmap`` ran at half its sets/s in a 64-set probe: 30 against 68 on the free
humanoid); with its default termination (relative cost change 1e-5), and with its tolerances
at 1e-12 so that it runs until it meets our tolerance or its 100 iterations.  Ours: ``ik.solve`` with ``LevenbergMarquardt(100, 1e-4)``,
``early_exit``.  Converged: every effector within 1e-4 m; limits: the worst hinge angle
outside its range.

Run: ``python benchmarks/ik_pyroki.py [--n 1000]``; writes ``benchmarks/results/ik_pyroki.json``.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from _common import time_call  # noqa: E402
from ik_throughput import random_poses  # noqa: E402

from jaxsim import ik  # noqa: E402


def urdf_of(sk) -> str:
    """A URDF of the skeleton: ball joints as three revolutes, hinges as one, fixed as fixed."""
    out = ['<robot name="humanoid">', '<link name="world"/>']
    for i, name in enumerate(sk.names):
        parent = "world" if sk.parents[i] < 0 else sk.names[sk.parents[i]]
        xyz = " ".join(f"{v:.9g}" for v in np.asarray(sk.offsets[i], np.float64))
        lim = None if sk.limits is None else sk.limits[i]
        if isinstance(lim, ik.Fixed):
            out += [f'<link name="{name}"/>', f'<joint name="{name}_fixed" type="fixed"><parent link="{parent}"/>'
                    f'<child link="{name}"/><origin xyz="{xyz}"/></joint>']
            continue
        if isinstance(lim, ik.Hinge):
            ax = " ".join(f"{v:.9g}" for v in lim.axis)
            out += [f'<link name="{name}"/>', f'<joint name="{name}_h" type="revolute"><parent link="{parent}"/>'
                    f'<child link="{name}"/><origin xyz="{xyz}"/><axis xyz="{ax}"/>'
                    f'<limit lower="{lim.lo:.9g}" upper="{lim.hi:.9g}" effort="1" velocity="1"/></joint>']
            continue
        links = [f"{name}_x", f"{name}_y", name]
        prev = parent
        for k, (link, ax) in enumerate(zip(links, ("1 0 0", "0 1 0", "0 0 1"))):
            origin = xyz if k == 0 else "0 0 0"
            out += [f'<link name="{link}"/>', f'<joint name="{link}_r" type="revolute"><parent link="{prev}"/>'
                    f'<child link="{link}"/><origin xyz="{origin}"/><axis xyz="{ax}"/>'
                    f'<limit lower="-6.3" upper="6.3" effort="1" velocity="1"/></joint>']
            prev = link
    out.append("</robot>")
    return "\n".join(out)


def pyroki_solver(sk, effectors, limited: bool, tight: bool):
    import jaxlie
    import jaxls
    import pyroki as pk
    import yourdfpy

    urdf = yourdfpy.URDF.load(io.StringIO(urdf_of(sk)), build_scene_graph=True, load_meshes=False)
    robot = pk.Robot.from_urdf(urdf)
    links = jnp.asarray([robot.links.names.index(sk.names[e]) for e in effectors], jnp.int32)
    hinge = [robot.joints.actuated_names.index(f"{n}_h") for n, lim in zip(sk.names, sk.limits or ())
             if isinstance(lim, ik.Hinge)]

    def one(targets):  # (E, 3)
        var = robot.joint_var_cls(0)
        costs = [pk.costs.pose_cost(robot, var, jaxlie.SE3.from_translation(targets[k]), links[k], 1.0, 0.0)
                 for k in range(len(effectors))]
        if limited:
            costs.append(pk.costs.limit_cost(robot, var, 100.0))
        term = (jaxls.TerminationConfig(max_iterations=100, cost_tolerance=1e-12, gradient_tolerance=1e-12,
                                        parameter_tolerance=1e-12) if tight else jaxls.TerminationConfig(max_iterations=100))
        sol = jaxls.LeastSquaresProblem(costs, [var]).analyze().solve(verbose=False, linear_solver="dense_cholesky",
                                                                      termination=term)
        return sol[var]

    def run(T):
        cfg = jax.lax.map(one, T)
        pos = robot.forward_kinematics(cfg)[..., links, 4:]
        return cfg, jnp.sqrt(jnp.sum((pos - T) ** 2, -1))

    return jax.jit(run), robot, hinge


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1000)
    args = ap.parse_args()
    H = ik.humanoid(np.float32)
    eff = tuple(H.index(k) for k in ik.HUMANOID_EFFECTORS)
    hinge_only = H.with_limits(tuple(lim if isinstance(lim, (ik.Hinge, ik.Fixed)) else None for lim in H.limits))
    free = ik.humanoid(np.float32, limits=False)
    rows = []
    for case, sk, limited in (("free humanoid", free, False), ("hinge-only limits", hinge_only, True)):
        rng = np.random.default_rng(5)
        R = ik.project_limits(sk, random_poses(rng, (args.n, sk.num_joints)))
        T = jnp.asarray(np.asarray(ik.fk(sk, R).positions)[:, eff], jnp.float32)
        ours = jax.jit(lambda t, sk=sk: ik.solve(sk, t, solver=ik.LevenbergMarquardt(100, 1e-4), effectors=eff))
        timing = time_call(ours, T, repeats=5)
        res = ours(T)
        viol = float(jnp.max(ik.limit_violation(sk, res.rotations))) if limited else 0.0
        row = {"case": case, "solver": "jaxsim LM", "n": args.n, "solves_per_s": args.n / timing["run_s"],
               "compile_s": timing["compile_s"], "converged_fraction": float(jnp.mean(res.converged)),
               "max_limit_violation_rad": viol}
        rows.append(row)
        print(row, flush=True)
        for tight in (False, True):
            solve, robot, hinge = pyroki_solver(sk, eff, limited, tight)
            timing = time_call(solve, T, repeats=2)
            cfg, err = solve(T)
            viol = 0.0
            if limited:
                lo, hi = robot.joints.lower_limits[np.asarray(hinge)], robot.joints.upper_limits[np.asarray(hinge)]
                a = cfg[:, np.asarray(hinge)]
                viol = float(jnp.max(jnp.maximum(lo - a, a - hi)))
            row = {"case": case, "solver": "pyroki (tolerances 1e-12)" if tight else "pyroki (default termination)", "n": args.n, "solves_per_s": args.n / timing["run_s"],
                   "compile_s": timing["compile_s"], "converged_fraction": float(jnp.mean(jnp.all(err <= 1e-4, -1))),
                   "max_limit_violation_rad": max(viol, 0.0)}
            rows.append(row)
            print(row, flush=True)
    mine = {r["case"]: r["solves_per_s"] for r in rows if r["solver"] == "jaxsim LM"}
    best = {}
    for r in rows:
        if r["solver"] != "jaxsim LM":
            best[r["case"]] = max(best.get(r["case"], 0.0), r["solves_per_s"])
    ratios = {c: mine[c] / best[c] for c in mine}
    print("ours / PyRoki's best:", ratios, flush=True)
    out = os.path.join(os.path.dirname(__file__), "results", "ik_pyroki.json")
    with open(out, "w") as f:
        json.dump({"timestamp": time.strftime("%Y-%m-%dT%H:%M:%S"), "jax": jax.__version__, "rows": rows,
                   "ratio_ours_over_pyroki_best": ratios}, f, indent=1)
    print("wrote", out)


if __name__ == "__main__":
    main()
