"""Scale-out: batched IK and batched cloth rollouts split over 1, 2 and 4 forced host devices.

Each device count runs in its own subprocess with
``XLA_FLAGS=--xla_force_host_platform_device_count=D`` (the flag must be set before JAX
starts).  This machine has only 2 CPU cores, so 4 "devices" share 2 cores: the numbers
show what the sharding layer costs and gains on a CPU host, not a multi-GPU speedup.

* strong scaling: a fixed batch (100k IK targets; 8 cloth scenes) over D devices;
* weak scaling: a fixed batch per device (25k targets; 2 scenes), efficiency
  ``t(1 device, n) / t(D devices, D n)``.

Baseline in the same run: the same call with ``sharded=False`` in the 1-device process.
IK: float32, 6-joint unit chain, FABRIK, exactly 10 sweeps.  Cloth: float32, 16x16 grid,
lab parameters with stiffness 50..400 over the scenes, 30 implicit-Euler (CG) steps.

Run: ``python benchmarks/scaling.py``; writes ``benchmarks/results/scaling.json``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import write  # noqa: E402

WORKER = r"""
import json, sys
import jax, jax.numpy as jnp, numpy as np
sys.path.insert(0, sys.argv[1])
from _common import time_call
from jaxsim import cloth, ik
D = jax.local_device_count()
out = {"devices": D}
chain = ik.straight_chain(np.ones(5, np.float32), direction=(0, 1, 0))
chain = ik.Chain(np.asarray(chain.offsets, np.float32))
rng = np.random.default_rng(0)
def targets(n):
    d = rng.normal(size=(n, 3)); d /= np.linalg.norm(d, axis=1, keepdims=True)
    return jnp.asarray(d * rng.uniform(0.5, 4.5, size=(n, 1)), jnp.float32)
def ik_time(n, sharded):
    t = targets(n)
    r = time_call(lambda: ik.solve(chain, t[:, None], max_iters=10, tol=0.0, sharded=sharded).positions, repeats=5)
    return {"n": n, **r, "per_s": n / r["run_s"]}
out["ik_strong"] = ik_time(100_000, None)
out["ik_weak"] = ik_time(25_000 * D, None)
def scenes(b):
    return [cloth.replace(cloth.grid(15, 0.2, dtype=np.float32), stiffness=float(k)) for k in np.linspace(50, 400, b)]
def cloth_time(b, sharded):
    sc = cloth.stack_scenes(scenes(b))
    s0 = cloth.State.at_rest(scenes(1)[0])
    integ = cloth.ImplicitEuler(solver="cg")
    r = time_call(lambda: cloth.batch_rollout(sc, s0, 1 / 60, 30, integ, sharded=sharded)[0].x, repeats=3)
    return {"scenes": b, **r, "scene_steps_per_s": b * 30 / r["run_s"]}
out["cloth_strong"] = cloth_time(8, None)
out["cloth_weak"] = cloth_time(2 * D, None)
if D == 1:
    out["ik_unsharded_baseline"] = ik_time(100_000, False)
    out["cloth_unsharded_baseline"] = cloth_time(8, False)
print("RESULT" + json.dumps(out))
"""


def run(devices: int) -> dict:
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}", JAX_PLATFORMS="cpu")
    print(f"[scaling] {devices} device(s) ...", flush=True)
    r = subprocess.run([sys.executable, "-c", WORKER, os.path.dirname(os.path.abspath(__file__))], env=env,
                       capture_output=True, text=True, check=True)
    line = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT")][-1]
    return json.loads(line[len("RESULT"):])


def main() -> None:
    rows = [run(d) for d in (1, 2, 4)]
    one = rows[0]
    summary = []
    for r in rows:
        D = r["devices"]
        s = {
            "devices": D,
            "ik_strong_M_per_s": r["ik_strong"]["per_s"] / 1e6,
            "ik_strong_speedup": one["ik_strong"]["run_s"] / r["ik_strong"]["run_s"],
            "ik_weak_efficiency": one["ik_weak"]["run_s"] / r["ik_weak"]["run_s"],
            "cloth_strong_scene_steps_per_s": r["cloth_strong"]["scene_steps_per_s"],
            "cloth_strong_speedup": one["cloth_strong"]["run_s"] / r["cloth_strong"]["run_s"],
            "cloth_weak_efficiency": one["cloth_weak"]["run_s"] / r["cloth_weak"]["run_s"],
        }
        summary.append(s)
        print(f"[scaling] D={D}: IK {s['ik_strong_M_per_s']:.2f} M/s (x{s['ik_strong_speedup']:.2f}), weak eff "
              f"{s['ik_weak_efficiency']:.2f}; cloth {s['cloth_strong_scene_steps_per_s']:.0f} scene-steps/s "
              f"(x{s['cloth_strong_speedup']:.2f}), weak eff {s['cloth_weak_efficiency']:.2f}")
    base = one["ik_unsharded_baseline"]["run_s"] / one["ik_strong"]["run_s"]
    print(f"[scaling] one device, sharded=None vs sharded=False time ratio: IK {1 / base:.3f}, cloth "
          f"{one['cloth_strong']['run_s'] / one['cloth_unsharded_baseline']['run_s']:.3f}")
    write("scaling", {"cores": os.cpu_count(), "summary": summary, "raw": rows})


if __name__ == "__main__":
    main()
