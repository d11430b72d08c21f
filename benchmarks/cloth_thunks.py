"""Where a converged cloth step's compiled program spends its time, kernel by kernel.

XLA:CPU runs a compiled program as a sequence of kernels ("thunks"), one per fusion or
library call, and pays a fixed cost for each.  This script traces warm calls of one
converged step (``jax.profiler.trace`` with ``XLA_FLAGS=--xla_cpu_enable_xprof_traceme=true``,
read back with ``jax``'s own profile reader) and groups the kernels by how often they ran
per step: once per step, once per Newton iteration, once per CG iteration.  Times are
summed over the kernels' own spans and inflated by the tracing itself, so compare shares
and counts, not milliseconds, with the untraced benchmarks.

Scenes: B 32x32 (block Jacobi) and C 32x32 k = 1e3 (two-level), float64, 30 steps into the
motion, ``ImplicitEuler(linear_solver=CG(tol=1e-6, forcing=0), tol=1e-6)``.

Run: ``python benchmarks/cloth_thunks.py``; writes ``benchmarks/results/cloth_thunks.json``.
"""

from __future__ import annotations

import collections
import glob
import os
import shutil
import sys
import tempfile

os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_enable_xprof_traceme=true").strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
from jax._src.lib import _profile_data  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import write  # noqa: E402

import jaxsim  # noqa: E402
from jaxsim import cloth as C  # noqa: E402

REPS = 10


def kernel_spans(fn, *args):
    """``{kernel name: (total ns, count)}`` over ``REPS`` warm calls of ``fn``."""
    jax.block_until_ready(fn(*args))
    d = tempfile.mkdtemp()
    try:
        with jax.profiler.trace(d):
            for _ in range(REPS):
                jax.block_until_ready(fn(*args))
        pb = glob.glob(os.path.join(d, "**", "*.xplane.pb"), recursive=True)[0]
        data = _profile_data.ProfileData.from_file(pb)
    finally:
        shutil.rmtree(d)
    spans = collections.defaultdict(lambda: [0, 0])
    for plane in data.planes:
        for line in plane.lines:
            if not line.name.startswith("tf_XLA"):
                continue
            for ev in line.events:
                name = ev.name
                if name.startswith(("end:", "while", "cond")) or "ThunkExecutor" in name:
                    continue  # loop and branch spans contain their kernels
                spans[name][0] += ev.duration_ns
                spans[name][1] += 1
    return spans


def case(label, scene, dt, integ):
    warm, _ = C.rollout(scene, C.State.at_rest(scene), dt, 30,
                        C.ImplicitEuler(linear_solver=C.CG(integ.linear(scene.num_particles).preconditioner, tol=1e-10), tol=1e-8))
    s0 = C.State(warm.x[-1], warm.v[-1])
    fn = jax.jit(lambda s: C.step(scene, s, dt, integ))
    _, info = fn(s0)
    newton, cg = int(info.newton_iters), int(info.cg_iters)
    spans = kernel_spans(fn, s0)
    groups = {"once per step": 1, "per Newton iteration": newton, "per CG iteration": cg}
    rows = []
    for group, per in groups.items():
        ks = [(n, t, c) for n, (t, c) in spans.items() if round(c / REPS) == per]
        us = sum(t for _, t, _ in ks) / 1e3 / REPS
        rows.append({"group": group, "runs_per_step": per, "kernels": len(ks), "traced_us_per_step": us})
    total = sum(t for t, _ in spans.values()) / 1e3 / REPS
    calls = sum(c for _, c in spans.values()) / REPS
    print(f"{label}: Newton {newton}, CG {cg}, {calls:.0f} kernel runs per step, {total:.0f} us traced", flush=True)
    for r in rows:
        print(f"  {r['group']:22s} x{r['runs_per_step']:4d}: {r['kernels']:4d} kernels, {r['traced_us_per_step']:8.0f} us",
              flush=True)
    top = sorted(spans.items(), key=lambda kv: -kv[1][0])[:12]
    return {"scene": label, "newton": newton, "cg": cg, "kernel_runs_per_step": calls, "traced_us_per_step": total,
            "groups": rows, "top": [{"kernel": n, "traced_us_per_step": t / 1e3 / REPS, "runs_per_step": c / REPS}
                                    for n, (t, c) in top]}


def main():
    jaxsim.retain_host_memory()  # benchmarks/host_memory.py: what this changes
    E = C.ImplicitEuler
    out = [case("B 32x32", C.grid(31, 0.2), 1 / 60, E(linear_solver=C.CG(tol=1e-6, forcing=0.0), tol=1e-6)),
           case("C 32x32 k=1e3 two-level", C.grid(31, 0.2, mass=1.0 / 1024, stiffness=1e3, gravity=9.8), 1 / 30,
                E(linear_solver=C.CG(C.TwoLevel(), tol=1e-6, forcing=0.0), tol=1e-6))]
    write("cloth_thunks", {"reps": REPS, "rows": out})


if __name__ == "__main__":
    main()
