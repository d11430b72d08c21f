"""Float32 friction's smoothing velocity: ``FRICTION_EPS_V`` at 1e-4 m/s (float64's, the value
before float32 had its own) against float32's 1e-3 m/s, on the drape.

``cloth_substeps.py``'s drape (0.5 kg, 1.2 m square, k = 1e3, damping 0.01, dropped onto a
sphere over a floor, friction 0.4, dt = 1/60, 60 steps from rest), float32, default
``ImplicitEuler()`` and without substeps (``max_substep_depth=0``).  Each case runs in a
process of its own (the value is read when the step is traced), alternating the two
values; per case: converged steps, substeps, Newton iterations per step, the closest
approach to a collider and the warm rollout time (compile apart).

Run: ``python benchmarks/cloth_friction_eps.py [--quick]``; writes
``benchmarks/results/cloth_friction_eps.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
VALUES = (1e-4, 1e-3)


def one(n: int, depth: int, eps_v: float) -> dict:
    """The drape ``n x n`` in float32 with float32's ``eps_v`` set to ``eps_v`` (run in a child)."""
    import jax
    import numpy as np

    sys.path.insert(0, HERE)
    from _common import time_call
    from cloth_substeps import drape

    from jaxsim import cloth as C
    from jaxsim.cloth._implicit import contact as ct

    ct.FRICTION_EPS_V[np.dtype(np.float32)] = eps_v
    cloth = drape(n, np.float32)
    s0 = C.State.at_rest(cloth)
    f = jax.jit(lambda s: C.rollout(cloth, s, 1 / 60, 60, C.ImplicitEuler(max_substep_depth=depth)))
    t = time_call(f, s0, repeats=1)
    states, inf = f(s0)
    x = np.asarray(states.x, np.float64)
    gap = min(np.linalg.norm(x - np.array([0.0, 0.5, 0.0]), axis=-1).min() - 0.35, x[..., 1].min())
    conv = np.asarray(inf.converged)
    return {"n": n, "max_substep_depth": depth, "eps_v": eps_v, "converged_share": float(conv.mean()),
            "unconverged_steps": np.flatnonzero(~conv).tolist(), "substeps_total": int(np.sum(inf.substeps)),
            "newton_per_step": float(np.mean(inf.newton_iters)), "closest_m": float(gap),
            "ms_per_step": 1e3 * t["run_s"] / 60, "compile_s": t["compile_s"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="24x24 only")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        n, depth, eps_v = args.child
        print(json.dumps(one(int(n), int(depth), float(eps_v))))
        return
    sys.path.insert(0, HERE)
    from _common import write

    cases = [(24, 0), (24, 4)] + ([] if args.quick else [(32, 0), (32, 4), (64, 4)])
    rows = []
    for n, depth in cases:
        for eps_v in VALUES:
            out = subprocess.run([sys.executable, os.path.abspath(__file__), "--child", str(n), str(depth), str(eps_v)],
                                 check=True, capture_output=True, text=True).stdout
            row = json.loads(out.strip().splitlines()[-1])
            print(f"drape {n}x{n} depth {depth} eps_v {eps_v:g}: converged {100 * row['converged_share']:.1f}%, "
                  f"substeps {row['substeps_total']}, Newton {row['newton_per_step']:.1f}/step, "
                  f"{row['ms_per_step']:.1f} ms/step, closest {row['closest_m']:.1e} m", flush=True)
            rows.append(row)
    write("cloth_friction_eps", {"benchmark": "cloth_friction_eps", "quick": args.quick, "rows": rows})


if __name__ == "__main__":
    main()
