"""Stability sweep of implicit Euler (line search on): stiffness x time step, 200 steps.

Scenes: the lab cloth and a 24x24-particle lab-like grid.  For every (k, dt): is the
state finite, is the final total energy (kinetic + spring + gravity) at most the
initial one, and how many single steps raised the energy, by how much at most.

Run: ``python benchmarks/cloth_stability.py [--steps 200]``; writes
``benchmarks/results/cloth_stability.json`` and prints a markdown table.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp

sys.path.insert(0, __import__("os").path.dirname(__file__))
from _common import write  # noqa: E402

from jaxsim import cloth as C  # noqa: E402

KS = (1e2, 1e4, 1e6, 1e7)
DTS = (1 / 600, 1 / 60, 1 / 30, 1 / 10)


def sweep(scene, steps, integrator, ks=KS, dts=DTS, progress=None, rollout=C.rollout):
    """One rollout per ``(k, dt)`` cell; ``rollout`` is ``C.rollout`` or a callable like it."""
    rows = []
    s0 = C.State.at_rest(scene)
    for k in ks:
        c = C.replace(scene, stiffness=jnp.full_like(scene.stiffness, k))
        for dt in dts:
            t0 = time.perf_counter()
            states, infos = rollout(c, s0, dt, steps, integrator)
            rep = C.energy_report(c, s0, states, infos)
            jax.block_until_ready(rep)
            rows.append({
                "k": k, "dt": dt, "finite": bool(rep.finite), "stable": bool(rep.stable),
                "energy_not_above_initial": bool(rep.net_change <= 0), "E0": float(rep.energy[0]),
                "E_end": float(rep.energy[-1]), "rises": int(rep.rises), "max_rise": float(rep.max_rise),
                "max_newton": int(jnp.max(infos.newton_iters)), "mean_newton": float(jnp.mean(infos.newton_iters)),
                "max_cg": int(jnp.max(infos.cg_iters)), "backtracks": int(jnp.sum(infos.backtracks)),
                "converged_fraction": float(jnp.mean(infos.converged)), "seconds": time.perf_counter() - t0,
            })
            if progress:
                progress(rows[-1])
    return rows


def table(rows, title):
    out = [f"**{title}**", "", "| k (N/m) | dt (s) | finite | E_end <= E0 | steps with rise | max rise (J) | Newton mean/max | backtracks | converged |",
           "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['k']:.0e} | 1/{round(1 / r['dt'])} | {r['finite']} | {r['energy_not_above_initial']} | {r['rises']} | "
                   f"{r['max_rise']:.2e} | {r['mean_newton']:.1f}/{r['max_newton']} | {r['backtracks']} | {100 * r['converged_fraction']:.0f}% |")
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=200)
    args = ap.parse_args()
    jax.config.update("jax_enable_x64", True)
    scenes = {"lab cloth (11x11)": C.lab_cloth(), "24x24 grid": C.grid(23, 0.2)}
    integ = C.ImplicitEuler(newton_iters=20, tol=1e-6)
    out = {}
    for name, sc in scenes.items():
        print(f"[stability] {name}: {len(KS) * len(DTS)} runs of {args.steps} steps", flush=True)
        rows = sweep(sc, args.steps, integ, progress=lambda r: print(
            f"  k={r['k']:.0e} dt=1/{round(1 / r['dt'])}: finite={r['finite']} rises={r['rises']} "
            f"max_rise={r['max_rise']:.2e} {r['seconds']:.1f}s", flush=True))
        out[name] = rows
        print(table(rows, name))
    write("cloth_stability", {"steps": args.steps, "integrator": repr(integ), "dtype": "float64", "scenes": out})


if __name__ == "__main__":
    main()
