"""Memory per target of a batched IK solve, with and without the per-sweep ``trace``.

XLA's compiled memory analysis (``jax.jit(f).lower(...).compile().memory_analysis()``) of
``ik.fabrik`` and ``ik.ccd`` on the 6-joint unit chain, float32, 100 sweeps (the
defaults), at two batch sizes; bytes per target are the slope between them, so fixed
costs drop out.  Outputs (rotations, positions, error, ...) count with temporaries.

Run: ``python benchmarks/ik_memory.py``; writes ``benchmarks/results/ik_memory.json``.
"""

from __future__ import annotations

import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import write  # noqa: E402

from jaxsim import ik  # noqa: E402

SIZES = (10_000, 100_000)


def footprint(solver, n, trace):
    chain = ik.straight_chain(np.ones(5, np.float32))
    t = jax.ShapeDtypeStruct((n, 3), jnp.float32)
    f = jax.jit(lambda tg: getattr(ik, solver)(chain, tg[:, None], trace=trace))
    m = f.lower(t).compile().memory_analysis()
    return m.temp_size_in_bytes + m.output_size_in_bytes + m.argument_size_in_bytes


def main() -> None:
    rows = []
    for solver in ("fabrik", "ccd"):
        for trace in (True, False):
            b = [footprint(solver, n, trace) for n in SIZES]
            per = (b[1] - b[0]) / (SIZES[1] - SIZES[0])
            rows.append({"solver": solver, "trace": trace, "bytes": dict(zip(map(str, SIZES), b)), "bytes_per_target": per,
                         "GB_for_10M_targets": per * 1e7 / 1e9})
            print(f"{solver:6s} trace={trace!s:5s} {per:7.0f} B/target -> {per * 1e7 / 1e9:.2f} GB for 10M targets", flush=True)
    write("ik_memory", {"chain": "6 joints, float32", "max_iters": 100, "rows": rows})


if __name__ == "__main__":
    main()
