"""Where a converged implicit cloth step spends its time: the pieces of one Newton iteration.

Scene: the B 32x32 grid (lab parameters), float64, positions perturbed by 1 cm.  Each piece
is jit-compiled alone and timed warm (median of repeats, compile apart), next to the
baseline of an elementwise no-op on the same array.  The CG operator ``H p`` is timed both
ways: by the grid operator (shifted slices, what a grid scene uses) and by the general one
(gathers through ``ParticleLayout.incidence``, the same scene with its springs in another order), each
alone and as 50 applications inside one ``fori_loop`` (per application, without the
dispatch cost).

Run: ``python benchmarks/cloth_profile.py``; writes ``benchmarks/results/cloth_profile.json``.
"""

from __future__ import annotations

import os
import sys

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import time_call, write  # noqa: E402

import jaxsim  # noqa: E402
from jaxsim import cloth as C  # noqa: E402
from jaxsim.cloth._model import energy as en  # noqa: E402
from jaxsim.cloth._layout import layout_of, spring_diff, spring_sum  # noqa: E402
from jaxsim.cloth._vec import matvec  # noqa: E402
from jaxsim.cloth._implicit.hessian import block_jacobi  # noqa: E402
from jaxsim.cloth._implicit.problem import StepProblem, gradient, incremental_potential, objective, spring_terms  # noqa: E402


def main() -> None:
    jaxsim.retain_host_memory()  # benchmarks/host_memory.py: what this changes
    c = C.grid(31, 0.2)
    s = C.State.at_rest(c)
    x = s.x + 0.01 * jax.random.normal(jax.random.PRNGKey(0), s.x.shape)
    p = StepProblem.build(c, s.x, s.v, jnp.asarray(1 / 60))
    u = x - s.x  # the step's unknown is the displacement
    i, j = c.springs[:, 0], c.springs[:, 1]
    perm = np.random.default_rng(0).permutation(c.num_springs)  # no grid layout: the general operator
    g = C.replace(c, springs=np.asarray(c.springs)[perm], rest_length=c.rest_length[perm], stiffness=c.stiffness[perm])
    lc, lg = layout_of(c.springs, c.rest), layout_of(g.springs, g.rest)
    assert type(lc).__name__ == "PlanarLayout" and type(lg).__name__ == "ParticleLayout"
    A = en.element_blocks(c, x, None, project_psd=True)

    def analytic_blocks(x):
        d = x[j] - x[i]
        l = jnp.linalg.norm(d, axis=-1)
        e = d / l[:, None]
        eeT = e[:, :, None] * e[:, None, :]
        return c.stiffness[:, None, None] * eeT + jnp.maximum(c.stiffness * (1 - c.rest_length / l), 0)[:, None, None] * (jnp.eye(3) - eeT)

    pieces = {
        "no-op (x + 1)": (lambda x: x + 1.0, x),
        "objective g(w)": (lambda u: incremental_potential(u, p), u),
        "gradient of g (jax.grad)": (lambda u: jax.grad(incremental_potential)(u, p), u),
        "g, its gradient and spring terms, radial form (Newton's evaluation)":
            (lambda u: (lambda t: (objective(u, p, t), gradient(u, p, t), t))(spring_terms(u, p)), u),
        "spring blocks, radial form by autodiff (+ PSD)": (lambda x: en.element_blocks(c, x, None, project_psd=True), x),
        "spring blocks, closed form (reference only)": (analytic_blocks, x),
        "CG operator H p (grid operator)": (lambda p: spring_sum(c, matvec(A, spring_diff(c, p, lc)), layout=lc), x),
        "CG operator H p (general, gathers)": (lambda p: spring_sum(g, matvec(A[perm], spring_diff(g, p, lg)), layout=lg), x),
        "block-Jacobi setup + apply": (lambda A: block_jacobi(p, A)(x), A),
    }
    rows = []
    for name, (f, arg) in pieces.items():
        t = time_call(jax.jit(f), arg, repeats=50)
        rows.append({"piece": name, "ms": 1e3 * t["run_s"], "compile_s": t["compile_s"]})
        print(f"{name:70s} {1e3 * t['run_s']:.3f} ms", flush=True)
    for name in ("CG operator H p (grid operator)", "CG operator H p (general, gathers)"):
        f = pieces[name][0]
        loop = jax.jit(lambda v, f=f: jax.lax.fori_loop(0, 50, lambda k, v: v + 1e-6 * f(v), v))
        t = time_call(loop, x, repeats=20)
        rows.append({"piece": name + ", in a loop", "ms": 1e3 * t["run_s"] / 50, "compile_s": t["compile_s"]})
        print(f"{name + ', in a loop':45s} {1e3 * t['run_s'] / 50:.3f} ms", flush=True)
    # PCG's dot products: XLA:CPU runs the product of two (N, 3) operands as its own loop
    # before a tree reduction, far slower than a dot at N = 1024
    y = x[::-1]
    for name, dot in (("dot sum(u * v), in a loop", lambda u, v: jnp.sum(u * v)),
                      ("dot vdot(u, v), in a loop", lambda u, v: jnp.vdot(u.reshape(-1), v.reshape(-1)))):
        loop = jax.jit(lambda v, dot=dot: jax.lax.fori_loop(0, 200, lambda k, v: v * (1.0 + 1e-9 * dot(v, y)), v))
        t = time_call(loop, x, repeats=20)
        rows.append({"piece": name, "ms": 1e3 * t["run_s"] / 200, "compile_s": t["compile_s"]})
        print(f"{name:70s} {1e3 * t['run_s'] / 200:.4f} ms", flush=True)
    write("cloth_profile", {"scene": "B 32x32 float64", "rows": rows})


if __name__ == "__main__":
    main()
