"""Peak temporary memory of the gradient of a 600-step lab-cloth rollout, with and without
``checkpoint=True``.

The gradient of the final mean height with respect to the (scalar) stiffness is compiled
with ``jax.jit(jax.grad(...)).lower(...).compile()`` and XLA's ``memory_analysis()`` gives
the temporary buffer size, next to the size of the 600 stacked states (the floor any
O(T)-states scheme keeps).  Both gradients are evaluated and compared.  float64.

Run: ``python benchmarks/rollout_memory.py [--steps 600]``; writes
``benchmarks/results/rollout_memory.json``.
"""

from __future__ import annotations

import argparse
import os
import sys

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import time_call, write  # noqa: E402

from jaxsim import cloth as C  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=600)
    T = ap.parse_args().steps
    c = C.lab_cloth()
    s0 = C.State.at_rest(c)

    def loss(k, checkpoint):
        states, _ = C.rollout(C.replace(c, stiffness=k), s0, 1 / 60, T, checkpoint=checkpoint)
        return jnp.mean(states.x[-1, :, 1])

    rows = []
    for ck in (False, True):
        comp = jax.jit(jax.grad(loss), static_argnums=1).lower(150.0, ck).compile()
        mem = comp.memory_analysis()
        t = time_call(comp, 150.0, repeats=3)
        g = float(comp(150.0))
        rows.append({"checkpoint": ck, "temp_MB": mem.temp_size_in_bytes / 1e6, "grad": g, "run_s": t["run_s"]})
        print(f"checkpoint={ck}: {mem.temp_size_in_bytes / 1e6:.1f} MB temporaries, gradient {g:.15e}, "
              f"{t['run_s']:.2f} s per gradient", flush=True)
    states_MB = 2 * T * c.num_particles * 3 * 8 / 1e6
    rel = abs(rows[0]["grad"] - rows[1]["grad"]) / abs(rows[0]["grad"])
    print(f"stacked states (x and v): {states_MB:.1f} MB; relative gradient difference {rel:.1e}")
    write("rollout_memory", {"steps": T, "rows": rows, "states_MB": states_MB, "relative_grad_difference": rel})


if __name__ == "__main__":
    main()
