"""Implicit-function derivatives with joint limits and orientation targets: the bounds a
solution sits on are held (``jaxsim.ik._driver.implicit``), checked against finite differences of
re-solved problems where the solution is unique, and by the tangent conditions where not."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import ik
from jaxsim.ik._driver.implicit import _swing_twist
from jaxsim.ik._model.projection import hinge_angle
from jaxsim._geometry import quat as _quat


def planar_arm():
    """Two hinges about z (the first limited to [0, 0.5]) and an end effector: 2 parameters."""
    offsets = np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]])
    return ik.Skeleton(parents=(-1, 0, 1), offsets=offsets,
                       limits=(ik.Hinge((0, 0, 1), 0.0, 0.5), ik.Hinge((0, 0, 1), -2.5, 2.5), None))


LM = ik.LevenbergMarquardt(300, 0.0)  # tol 0: to the constrained minimum
MET = ik.LevenbergMarquardt(100, 1e-11)  # reachable targets, met to 1e-11


def angles(rot):
    return jnp.stack([hinge_angle(_quat.unstack(rot[j]), (0.0, 0.0, 1.0)) for j in (0, 1)])


def test_a_hinge_held_on_its_bound_matches_finite_differences():
    """The target pulls the first hinge past its bound, so it stays on it, and the second
    hinge alone brings the end nearest the target (out of reach): a unique constrained
    minimum, known in closed form, whose finite differences the derivative must equal."""
    arm = planar_arm()
    t0 = np.array([0.2, 1.6, 0.1])

    def exact(t):  # the first hinge at 0.5; the end on the line from the elbow to the target
        p1 = np.array([np.cos(0.5), np.sin(0.5)])
        a = np.arctan2(t[1] - p1[1], t[0] - p1[0])
        return np.concatenate([[0.0, 0.0], p1, p1 + [np.cos(a), np.sin(a)], [0.5, a - 0.5]])

    def solved(t, implicit):
        r = ik.solve(arm, t, solver=dataclasses.replace(LM, implicit_diff=implicit))
        return jnp.concatenate([r.positions[:, :2].reshape(-1), angles(r.rotations)])

    np.testing.assert_allclose(np.asarray(jax.jit(solved, static_argnums=1)(t0, False)), exact(t0), atol=1e-9)
    jac = np.asarray(jax.jit(jax.jacfwd(lambda t: solved(t, True)))(t0))
    h = 1e-6
    fd = np.stack([(exact(t0 + h * e) - exact(t0 - h * e)) / (2 * h) for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(jac, fd, atol=1e-8)
    # the held hinge never moves (a free one would: the match above fails without the hold)
    assert np.all(jac[-2] == 0.0) and np.abs(jac[-1, :2]).max() > 0.1


def test_a_joint_on_its_cone_stays_on_it_and_matches_finite_differences():
    """A bone on a 0.3 rad cone about y, pulled toward a target 1 rad off the axis: it rests
    on the cone at the target's azimuth (unique up to its twist), which finite differences
    of that closed form give; the swing angle, held, does not change to first order.  The
    Hessian must be the Lagrangian's: the plain one, in these coordinates, couples the
    twist and the swing and gives no motion at all."""
    y = jnp.array([0.0, 1.0, 0.0])
    sk = ik.Skeleton(parents=(-1, 0), offsets=np.array([[0.0, 0, 0], [0, 1.0, 0]]),
                     limits=(ik.SwingTwist(0.3, axis=(0, 1, 0)), None))
    t0 = np.array([1.2, 0.9, 0.5])

    def exact(t):
        phi = np.arctan2(t[2], t[0])
        return np.array([np.sin(0.3) * np.cos(phi), np.cos(0.3), np.sin(0.3) * np.sin(phi)])

    def out(t):
        r = ik.solve(sk, t, solver=dataclasses.replace(LM, implicit_diff=True))
        return r.positions[-1], _swing_twist(r.rotations[0], y)[0]

    end, swing = jax.jit(out)(t0)
    np.testing.assert_allclose(end, exact(t0), atol=1e-9)
    assert abs(float(swing) - 0.3) < 1e-12
    d_end, d_swing = jax.jit(jax.jacfwd(out))(t0)
    h = 1e-6
    fd = np.stack([(exact(t0 + h * e) - exact(t0 - h * e)) / (2 * h) for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(d_end, fd, atol=1e-8)
    assert np.abs(np.asarray(d_end)).max() > 0.1
    np.testing.assert_allclose(d_swing, 0.0, atol=1e-12)


def test_orientation_targets_are_followed():
    """Position and orientation of the end, met: its position follows the target (identity) and its
    frame follows the target frame (a tangent ``T (0, w/2)`` gives the same tangent)."""
    chain = ik.Chain(np.array([[0.0, 0, 0], [0, 1.0, 0], [0, 1.0, 0], [0, 0.5, 0]]))
    t0 = np.array([0.8, 1.5, 0.4])
    ang = 0.7
    o0 = np.array([np.cos(ang / 2), 0, 0, np.sin(ang / 2)])

    def end(t, o):
        r = ik.solve(chain, t, solver=dataclasses.replace(MET, implicit_diff=True), orientations=o[None],
                     orientation_weights=[1.0])
        G = ik.fk(chain, r.rotations).rotations[-1]
        return r.positions[-1], G * jnp.sign(jnp.sum(G * o)), r.converged

    p, G, conv = end(t0, o0)
    assert bool(conv)
    jit_end = jax.jit(lambda t, o: end(t, o)[:2])
    dp, _ = jax.jvp(jit_end, (t0, o0), (np.array([0.3, -0.2, 0.5]), np.zeros(4)))[1]
    np.testing.assert_allclose(dp, [0.3, -0.2, 0.5], atol=1e-8)
    w = np.array([0.2, -0.4, 0.1])
    do = np.asarray(_quat.stack(_quat.mul(_quat.unstack(jnp.asarray(o0)), (0.0, *(0.5 * w)))))
    dp, dG = jax.jvp(jit_end, (t0, o0), (np.zeros(3), do))[1]
    np.testing.assert_allclose(dp, 0.0, atol=1e-8)
    np.testing.assert_allclose(dG, do, atol=1e-8)


def test_gradients_finite_at_a_straight_arm_on_its_bound():
    """A straight arm whose hinges rest on their bound (0): finite, NaN-free gradients, in
    reach and out of it."""
    offsets = np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]])
    arm = ik.Skeleton(parents=(-1, 0, 1), offsets=offsets,
                      limits=(ik.Hinge((0, 0, 1), 0.0, 1.0), ik.Hinge((0, 0, 1), 0.0, 1.0), None))
    f = jax.jit(jax.grad(lambda t: jnp.sum(ik.solve(arm, t, solver=dataclasses.replace(LM, implicit_diff=True)).positions ** 2)))
    for t in (np.array([2.0, 0.0, 0.0]), np.array([3.0, 0.0, 0.0]), np.array([1.5, 0.3, 0.0])):
        assert np.all(np.isfinite(np.asarray(f(t)))), t


def test_lm_stops_at_a_stationary_point_and_flags_one_it_did_not_reach():
    """LM ends on a projected-gradient test: the planar arm held on its bound (its target
    out of reach) stops once no descent direction is left, long before 300 iterations,
    with ``stationary`` True and its implicit derivative that of the constrained minimum
    (the finite-difference check above).  A humanoid hand pulled 2 m out of reach is not
    stationary after LM's default 100 iterations: the result says so, so an implicit
    derivative taken there is flagged, not silently off."""
    arm = planar_arm()
    r = ik.solve(arm, np.array([0.2, 1.6, 0.1]), solver=LM)
    assert bool(r.stationary) and not bool(r.converged) and int(r.iterations) < 50
    H = ik.humanoid(np.float64)
    eff = ik.HUMANOID_EFFECTORS
    rest = np.asarray(ik.fk(H).positions)[[H.index(e) for e in eff]]
    far = rest + np.array([[0.0, 2.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    h = ik.solve(H, far, effectors=eff, solver=ik.LevenbergMarquardt(implicit_diff=True))
    assert not bool(h.converged) and not bool(h.stationary) and int(h.iterations) == 100
    assert ik.solve(arm, np.array([0.2, 1.6, 0.1]), solver=ik.FABRIK()).stationary is None  # LM only
