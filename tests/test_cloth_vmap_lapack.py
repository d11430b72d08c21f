"""No LAPACK call of a batched cloth program has a batch dimension.

jaxlib 0.10's batched LAPACK kernels split their batch over XLA:CPU's intra-op pool and
block until it is done; two at once (the Cholesky tries and the LU of a batched
``lax.cond``, which ``vmap`` evaluates both of) hung about half of the runs of a 2-scene
dense ``batch_rollout`` on 2 cores.  The solves are batched one matrix after another
instead (``_implicit.linsolve``); these tests read the traced programs, so they fail on
the old code deterministically, where a run would hang only now and then.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import cloth as C

from _helpers import all_eqns

jax.config.update("jax_enable_x64", True)

LAPACK = {"cholesky", "lu", "triangular_solve", "eigh", "qr", "svd", "schur", "tridiagonal_solve"}
SCENE = C.grid(4, 0.2, stiffness=300.0, gravity=9.8, damping=0.1, dtype=np.float64)


def batched_lapack(fn, *args):
    """The LAPACK equations of ``fn``'s jaxpr whose first operand has more than 2 axes."""
    jaxpr = jax.make_jaxpr(fn)(*args).jaxpr
    return [(e.primitive.name, e.invars[0].aval.shape) for e in all_eqns(jaxpr)
            if e.primitive.name in LAPACK and e.invars[0].aval.ndim > 2]


def _scenes():
    return C.stack_scenes([C.replace(SCENE, stiffness=SCENE.stiffness * k) for k in (1.0, 2.0)])


@pytest.mark.parametrize("integ", [C.ImplicitEuler(linear_solver=C.Cholesky()),
                                   C.ImplicitEuler(linear_solver=C.CG(preconditioner=C.TwoLevel())),
                                   C.BDF2(linear_solver=C.Cholesky())],
                         ids=["cholesky", "two_level", "bdf2"])
def test_batch_rollout_and_batched_gradients_batch_no_lapack_call(integ):
    scenes, s0 = _scenes(), C.State.at_rest(SCENE)
    fwd = lambda k: C.batch_rollout(C.replace(scenes, stiffness=scenes.stiffness * k), s0, 1 / 30, 2, integ)  # noqa: E731
    assert batched_lapack(fwd, jnp.asarray(1.0)) == []

    def loss(k):  # the implicit derivative's solve, batched over stiffness scales
        states, _ = C.rollout(C.replace(SCENE, stiffness=SCENE.stiffness * k), s0, 1 / 30, 2, integ)
        return jnp.sum(states.x[-1, :, 1])

    assert batched_lapack(jax.vmap(jax.grad(loss)), jnp.array([1.0, 2.0])) == []


def test_the_check_sees_a_batched_lapack_call():
    """The check itself can fail: a vmapped plain Cholesky is one batched call."""
    a = jnp.broadcast_to(jnp.eye(3), (2, 3, 3))
    assert batched_lapack(jax.vmap(jnp.linalg.cholesky), a) == [("cholesky", (2, 3, 3))]


def test_batched_dense_rollout_equals_per_scene_rollouts():
    integ = C.ImplicitEuler(linear_solver=C.Cholesky())
    s0 = C.State.at_rest(SCENE)
    states, infos = C.batch_rollout(_scenes(), s0, 1 / 30, 3, integ)
    assert bool(jnp.all(infos.converged))
    for i, k in enumerate((1.0, 2.0)):
        one, _ = C.rollout(C.replace(SCENE, stiffness=SCENE.stiffness * k), s0, 1 / 30, 3, integ)
        np.testing.assert_allclose(states.x[i], one.x, atol=1e-11)
