"""LM's limb start (``jaxsim.ik._solvers.limb_start``): a two-bone limb bent and swung onto its target."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import ik
from jaxsim.ik._solvers.limb_start import limb_start, limbs
from jaxsim.ik._model.limits import limit_table
from jaxsim.ik._model.skeleton import topology
from jaxsim.ik._model.stacked import fk_stacked
from jaxsim.ik._solvers.starts import default_start

from _helpers import random_rotations

#: root, a free shoulder, an elbow hinge bending 0 to 2.6 rad about z, and a wrist 0.05 off the
#: forearm's line: the effector is not on the hinge's plane through the shoulder's bone.
ARM = ik.Chain(np.array([[0.1, 0.2, 0.3], [0.0, 0.3, 0.0], [0.5, 0.0, 0.0], [0.4, 0.0, 0.05]]),
               limits=(None, None, ik.Hinge((0, 0, 1), 0.0, 2.6), None))


def _start(sk, eff, targets, L, swivel=None):
    topo, table = topology(sk.parents, eff), limit_table(sk)
    P, G = fk_stacked(topo.parents, sk.offsets, L)
    return limb_start(topo, table, L, P, G, targets, swivel)


def test_limbs_of_the_humanoid_and_of_a_chain():
    H = ik.humanoid()
    eff = tuple(H.index(n) for n in ik.HUMANOID_EFFECTORS)
    found = limbs(H.parents, eff, tuple(limit_table(H).kinds))
    names = [tuple(H.names[j] for j in limb[1:]) for limb in found]
    assert names == [("l_shoulder", "l_elbow", "l_hand"), ("r_shoulder", "r_elbow", "r_hand"),
                     ("l_hip", "l_knee", "l_ankle"), ("r_hip", "r_knee", "r_ankle")]
    # two hinges in a row: the nearest hinge's parent is no ball joint, so no limb
    two = ik.Chain(np.eye(4)[:, :3], limits=(None, ik.Hinge((0, 0, 1), 0, 2), ik.Hinge((0, 0, 1), 0, 2), None))
    assert limbs(two.parents, (3,), tuple(limit_table(two).kinds)) == ()
    L = jnp.asarray(default_start(two))
    assert _start(two, (3,), jnp.ones((1, 3)), L) is L


def test_a_reachable_target_is_met_exactly_and_the_swivel_keeps_it():
    """Targets between the arm's least and largest reach: the limb start puts the effector on
    the target (float64, 1e-9), with the hinge in range; a swivel turns the elbow about the
    shoulder-target line by that angle and keeps the effector on the target."""
    rng = np.random.default_rng(0)
    true = np.array(ik.project_limits(ARM, random_rotations(rng, (64, 4), np.pi)))
    true[:, 0] = (1.0, 0.0, 0.0, 0.0)  # the shoulder where the start has it: every target within reach
    T = jnp.asarray(np.asarray(ik.fk(ARM, true).positions)[:, 3:])
    L0 = jnp.broadcast_to(jnp.asarray(default_start(ARM)), (64, 4, 4))
    shoulder = np.asarray(ik.fk(ARM, L0).positions)[:, 1]
    for swivel in (None, 0.7, -2.0):
        L = jax.vmap(lambda t, l: _start(ARM, (3,), t, l, swivel))(T, L0)
        P = np.asarray(ik.fk(ARM, L).positions)
        np.testing.assert_allclose(P[:, 3], T[:, 0], atol=1e-9)
        assert float(jnp.max(ik.limit_violation(ARM, L))) <= 1e-12
        if swivel is None:
            base = P
            continue
        axis = (T[:, 0] - shoulder) / np.linalg.norm(T[:, 0] - shoulder, axis=-1, keepdims=True)

        def across(p):
            d = p[:, 2] - shoulder
            return d - np.sum(d * axis, -1, keepdims=True) * axis

        a, b = across(base), across(P)
        ang = np.arctan2(np.sum(axis * np.cross(a, b), -1), np.sum(a * b, -1))
        np.testing.assert_allclose(ang, swivel, atol=1e-9)


def test_out_of_reach_and_on_the_shoulder_no_nan():
    """A target beyond reach straightens the arm toward it; one on the shoulder folds it to
    the hinge's bound: finite, within the limits, and no NaN in the gradient."""
    L0 = jnp.asarray(default_start(ARM))
    shoulder = np.asarray(ik.fk(ARM, L0).positions)[1]
    far = jnp.asarray(shoulder + np.array([3.0, 0.0, 0.0]))[None]
    L = _start(ARM, (3,), far, L0)
    P = np.asarray(ik.fk(ARM, L).positions)
    assert abs(np.linalg.norm(P[3] - far[0]) - (3.0 - np.linalg.norm(P[3] - shoulder))) < 1e-9  # on the line
    for t in (far, jnp.asarray(shoulder)[None]):
        g = jax.grad(lambda tt: jnp.sum(_start(ARM, (3,), tt, L0)))(t)
        assert np.all(np.isfinite(np.asarray(g)))
        assert float(ik.limit_violation(ARM, _start(ARM, (3,), t, L0)).max()) <= 1e-12


def test_lm_starts_the_humanoid_lower_and_converges_in_fewer_iterations():
    """On limited-humanoid sets, LM from its own start (limbs bent) converges in fewer iterations
    than from the same default pose given by the caller, and no less often (a property of a
    sample: 64 sets, where the own start converges 64 against 61; on 32 of them, one set
    goes the other way).  From its own start LM converges on every set: without the ball
    joints' active set (``_active_set.tangent_balls``) it converged on 52 of the 64."""
    H = ik.humanoid()
    eff = tuple(H.index(n) for n in ik.HUMANOID_EFFECTORS)
    rng = np.random.default_rng(1)
    T = np.asarray(ik.fk(H, ik.project_limits(H, random_rotations(rng, (64, H.num_joints), np.pi))).positions)[:, eff]
    settings = ik.LevenbergMarquardt(30, 1e-6)
    own = ik.solve(H, T, solver=settings, effectors=eff)
    given = ik.solve(H, T, solver=settings, effectors=eff, rotations=default_start(H))
    assert float(jnp.mean(own.iterations)) < float(jnp.mean(given.iterations))
    assert int(jnp.sum(own.converged)) >= int(jnp.sum(given.converged))
    assert bool(jnp.all(own.converged))
