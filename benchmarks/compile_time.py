"""First-call compile time of each public entry point, on the default call, in float32.

Each case runs in a fresh Python process with no persistent compilation cache, so its
first call pays the whole trace, lowering and XLA compile, as a user's first call does.
Reported per case: the first call's wall time, a warm call's, their difference
(``compile_s``), and what JAX's own monitoring events add up to (traces, lowerings and
backend compiles, with their counts).  Bounds (from the issue tracker's targets): LM on the
limited humanoid <= 5 s, every chain call <= 2 s, a 32x32 cloth rollout <= 10 s.

Run: ``python benchmarks/compile_time.py [--only NAME ...] [--out compile_time]``;
writes ``benchmarks/results/compile_time.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

#: ``name -> (bound in seconds or None, setup code, the call)``: the call is timed twice.
CASES = {
    "ik chain, 1000 (N, 3) targets": (2.0, """
import numpy as np, jax.numpy as jnp
from jaxsim import ik
arm = ik.lab_arm()
T = jnp.asarray(np.asarray(arm.root) + np.random.default_rng(0).uniform(-1.2, 1.2, (1000, 3)), jnp.float32)
""", "ik.solve(arm, T)"),
    "ik chain, one target": (2.0, """
import numpy as np, jax.numpy as jnp
from jaxsim import ik
arm = ik.lab_arm()
T = jnp.asarray([0.6, 0.3, 0.4], jnp.float32)
""", "ik.solve(arm, T)"),
    "ik humanoid FABRIK, 1000 sets": (None, """
import numpy as np, jax.numpy as jnp
from jaxsim import ik
H = ik.humanoid(np.float32, limits=False)
eff = ik.HUMANOID_EFFECTORS
rest = np.asarray(ik.fk(H).positions)[[H.index(n) for n in eff]]
T = jnp.asarray(rest + np.random.default_rng(0).normal(0, 0.1, (1000, 4, 3)), jnp.float32)
""", "ik.solve(H, T, effectors=eff)"),
    "ik limited humanoid LM, 1000 sets": (5.0, """
import numpy as np, jax.numpy as jnp
from jaxsim import ik
H = ik.humanoid(np.float32)
eff = ik.HUMANOID_EFFECTORS
rest = np.asarray(ik.fk(H).positions)[[H.index(n) for n in eff]]
T = jnp.asarray(rest + np.random.default_rng(0).normal(0, 0.1, (1000, 4, 3)), jnp.float32)
""", "ik.solve(H, T, effectors=eff)"),
    "cloth lab cloth rollout, 60 steps": (None, """
from jaxsim import cloth as C
c = C.lab_cloth()
s0 = C.State.at_rest(c)
""", "C.rollout(c, s0, 1 / 60, 60)"),
    "cloth 32x32 drape on a sphere, 10 steps": (10.0, """
from jaxsim import cloth as C
ball = C.Sphere((0.0, 0.5, 0.0), 0.35, friction=0.4)
c = C.grid(31, 1.0 / 31, origin=(-0.5, 0.95, -0.5), mass=0.25 / 1024, stiffness=1e3, damping=0.01, gravity=9.8,
           pins=[], colliders=(ball,))
s0 = C.State.at_rest(c)
""", "C.rollout(c, s0, 1 / 60, 10)"),
    "cloth self-contact, two 8x8 layers, 10 steps": (None, """
import numpy as np
from jaxsim import cloth as C
top = C.grid(7, 1 / 7, origin=(-0.5, 0.98, -0.5)).rest
low = C.grid(7, 1 / 7, origin=(-0.49, 0.95, -0.49)).rest
T1 = C.grid_triangles(7)
ball = C.Sphere((0.0, 0.5, 0.0), 0.35, friction=0.4)
c = C.from_mesh(np.concatenate([top, low]), np.concatenate([T1, T1 + 64]), stiffness=1e3, damping=0.01,
                density=0.25, dtype=np.float32, colliders=(ball,), self_contact=True)
s0 = C.State.at_rest(c)
""", "C.rollout(c, s0, 1 / 60, 10)"),
}

CHILD = """
import json, time, sys
import jax
stats = {"traces": [0, 0.0], "lowerings": [0, 0.0], "compiles": [0, 0.0]}
names = {"/jax/core/compile/jaxpr_trace_duration": "traces",
         "/jax/core/compile/jaxpr_to_mlir_module_duration": "lowerings",
         "/jax/core/compile/backend_compile_duration": "compiles"}
def on(event, secs, **kw):
    if event in names:
        stats[names[event]][0] += 1; stats[names[event]][1] += secs
jax.monitoring.register_event_duration_secs_listener(on)
t0 = time.perf_counter()
{setup}
setup_s = time.perf_counter() - t0
before = json.loads(json.dumps(stats))
t0 = time.perf_counter(); jax.block_until_ready({call}); first = time.perf_counter() - t0
during = {k: [stats[k][0] - before[k][0], stats[k][1] - before[k][1]] for k in stats}
warm = []
for _ in range(3):
    t0 = time.perf_counter(); jax.block_until_ready({call}); warm.append(time.perf_counter() - t0)
warm = sorted(warm)[1]
print("RESULT " + json.dumps({"setup_s": setup_s, "first_s": first, "warm_s": warm, "compile_s": max(first - warm, 0.0),
                              "jax": {k: {"count": v[0], "seconds": round(v[1], 3)} for k, v in during.items()}}))
"""


def run_case(name: str) -> dict:
    bound, setup, call = CASES[name]
    env = dict(os.environ)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env["JAX_ENABLE_COMPILATION_CACHE"] = "false"
    code = CHILD.replace("{setup}", setup.strip()).replace("{call}", call)
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    line = [x for x in out.stdout.splitlines() if x.startswith("RESULT ")]
    if out.returncode or not line:
        raise RuntimeError(f"{name} failed:\n{out.stderr[-3000:]}")
    row = json.loads(line[0][7:])
    row.update(name=name, call=call, bound_s=bound, process_s=wall,
               within_bound=None if bound is None else row["compile_s"] <= bound)
    return row


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="*", help="case names containing these words")
    p.add_argument("--out", default="compile_time")
    a = p.parse_args()
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from _common import write

    rows = []
    for name in CASES:
        if a.only and not any(w in name for w in a.only):
            continue
        row = run_case(name)
        rows.append(row)
        flag = "" if row["bound_s"] is None else f" (bound {row['bound_s']} s: {'ok' if row['within_bound'] else 'OVER'})"
        print(f"{name:48s} first {row['first_s']:6.2f} s  warm {row['warm_s']:7.3f} s  compile {row['compile_s']:6.2f} s"
              f"  [{row['jax']['compiles']['count']} XLA compiles {row['jax']['compiles']['seconds']:.2f} s]{flag}",
              flush=True)
    write(a.out, {"rows": rows, "note": "float32 defaults, fresh process per case, no persistent cache"})


if __name__ == "__main__":
    main()
