"""LM's active set on ball joints (``_active_set.tangent_balls``): the bound normals against autodiff,
and the held columns (what it buys on the limited humanoid: ``test_ik_limb_start.py``)."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import ik
from jaxsim._geometry import quat as _quat
from jaxsim.ik._model.limits import limit_table
from jaxsim.ik._solvers.active_set import bound_normals, tangent_balls
from jaxsim.ik._driver.implicit import _swing_twist_turned
from jaxsim.ik._solvers.residual import LMProblem, _dofs, jacobian_at
from jaxsim.ik._model.skeleton import topology
from jaxsim.ik._model.stacked import fk_stacked

from _helpers import random_rotations


def test_bound_normals_are_the_angles_gradients():
    """The swing and twist directions are ``jax.jacfwd`` of the two angles in the parameters
    (``_implicit``'s, which the implicit derivative holds its bounds by), up to positive factors
    (float64, 64 random rotations and axes); finite at no swing."""
    rng = np.random.default_rng(0)
    q = jnp.asarray(random_rotations(rng, (64,), np.pi))
    a = rng.normal(size=(64, 3))
    a = jnp.asarray(a / np.linalg.norm(a, axis=-1, keepdims=True))
    D = jax.vmap(jax.jacfwd(_swing_twist_turned), in_axes=(None, 0, 0))(jnp.zeros(3), q, a)
    _, _, Ds, Dt = bound_normals(_quat.unstack(q, axis=-1), _quat.unstack(a, axis=-1))

    def unit(v):
        return np.asarray(v) / np.linalg.norm(np.asarray(v), axis=-1, keepdims=True)

    np.testing.assert_allclose(unit(Ds), unit(D[:, 0]), atol=1e-12)
    np.testing.assert_allclose(unit(Dt), unit(D[:, 1]), atol=1e-12)
    one = _quat.unstack(jnp.asarray([[1.0, 0.0, 0.0, 0.0]]), axis=-1)
    out = bound_normals(one, _quat.unstack(jnp.asarray([[1.0, 0.0, 0.0]]), axis=-1))
    assert all(np.all(np.isfinite(np.asarray(jnp.stack(x) if isinstance(x, tuple) else x))) for x in out)


def _arm_on_its_cone(azimuth):
    """A two-bone chain whose root (cone 0.5 rad, twist +-0.3 rad about x) is turned 0.5 rad
    about the axis ``(0, cos azimuth, sin azimuth)`` (onto its cone): ``(skeleton, table,
    L (3, 4), P (3, 3), G (3, 4))``."""
    sk = ik.Chain(np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]]),
                  limits=(ik.SwingTwist(0.5, (-0.3, 0.3)), None, None))
    axis = np.array([0.0, np.cos(azimuth), np.sin(azimuth)])
    L = np.tile([1.0, 0, 0, 0], (3, 1))
    L[0] = (np.cos(0.25), *(np.sin(0.25) * axis))
    L = jnp.asarray(L)
    P, G = fk_stacked(sk.parents, jnp.asarray(sk.offsets), L)
    return sk, limit_table(sk), L, P, G


def test_a_ball_joint_on_its_cone_steps_along_it():
    """Descent that pushes the root out of its cone loses exactly its outward column component
    (the columns' product with the swing normal is 0, the rest unchanged); descent that pulls
    it inside leaves the Jacobian as it was."""
    for target, held in (((0.0, 3.0, 0.0), True), ((2.0, 0.0, 0.0), False)):
        sk, table, L, P, G = _arm_on_its_cone(np.pi / 2)  # turned about z: the bone swung toward +y
        prob = LMProblem(jnp.asarray([target]), jnp.ones(1))
        topo = topology(sk.parents, (2,))
        dofs = _dofs(topo, table, False)
        Jac, r = jacobian_at(topo, P, G, prob, dofs, table)
        out = tangent_balls(Jac, L, -(Jac.T @ r), dofs, table, Jac.dtype)
        _, _, Ds, _ = bound_normals(_quat.unstack(L[:1], axis=-1), _quat.unstack(table.axis[:1], axis=-1))
        u = np.asarray(Ds[0]) / np.linalg.norm(np.asarray(Ds[0]))
        cols = list(dofs.cols[0])
        if held:
            np.testing.assert_allclose(np.asarray(out[:, cols]) @ u, 0.0, atol=1e-14)
            assert np.linalg.norm(np.asarray(Jac[:, cols]) @ u) > 0.1  # it had an outward part
            np.testing.assert_allclose(out[:, cols], Jac[:, cols] - np.outer(np.asarray(Jac[:, cols]) @ u, u),
                                       atol=1e-14)
        else:
            np.testing.assert_array_equal(out, Jac)
        rest = [c for c in range(dofs.n) if c not in cols]
        np.testing.assert_array_equal(out[:, rest], Jac[:, rest])
