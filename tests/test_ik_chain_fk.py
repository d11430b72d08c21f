import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from _helpers import TOL, random_unit_quaternions
from jaxsim import ik


def quat_to_matrix(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def numpy_fk(offsets, rotations):
    """The lab's recursion as a plain loop over rotation matrices."""
    J = len(offsets)
    R = [quat_to_matrix(rotations[0])]
    P = [np.array(offsets[0], float)]
    for i in range(1, J):
        P.append(P[i - 1] + R[i - 1] @ offsets[i])
        R.append(R[i - 1] @ quat_to_matrix(rotations[i]))
    return np.array(P), np.array(R)


def test_lab_arm():
    arm = ik.lab_arm()
    assert arm.num_joints == 5
    np.testing.assert_allclose(arm.root, [0, 1.7, 0])
    np.testing.assert_allclose(arm.lengths, [0.8, 0.4, 0.2, 1.2], rtol=1e-6)
    np.testing.assert_allclose(arm.reach, 2.6, rtol=1e-6)
    pose = ik.fk(arm)
    np.testing.assert_allclose(pose.positions[-1], [0, -0.9, 0], atol=1e-6)
    np.testing.assert_allclose(pose.rotations, np.tile([1.0, 0, 0, 0], (5, 1)))


@pytest.mark.parametrize(
    "offsets, match",
    [
        (np.zeros((1, 3)), "at least 2 joints"),
        (np.zeros((4, 2)), "shape"),
        (np.zeros(3), "shape"),
        (np.array([[0, 0, 0], [0, 1.0, np.nan]]), "finite"),
        (np.array([[0, 0, 0], [0, np.inf, 0]]), "finite"),
    ],
)
def test_chain_rejects_bad_offsets(offsets, match):
    with pytest.raises(ValueError, match=match):
        ik.Chain(offsets)


def test_zero_length_bones_go_through_fk_but_not_the_solvers():
    """BVH rigs have joints at their parent's position: FK takes them, the solvers name them."""
    arm = ik.Chain(np.array([[0, 0, 0], [0, 1.0, 0], [0, 0, 0], [1.0, 0, 0]]))
    assert arm.zero_length_joints() == (2,)
    q = np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0], [np.cos(0.5), 0, 0, np.sin(0.5)], [1.0, 0, 0, 0]])
    P = np.asarray(ik.fk(arm, q).positions)
    np.testing.assert_allclose(P[2], P[1])
    np.testing.assert_allclose(P[3], P[2] + [np.cos(1.0), np.sin(1.0), 0], atol=1e-6)
    for solver in ("fabrik", "ccd", "lm"):
        with pytest.raises(ValueError, match=r"positive length; joint\(s\) \[2\]"):
            ik.solve(arm, np.array([[1.0, 1.0, 0]]), solver=solver)
    with pytest.raises(ValueError, match="zero length; give it axis="):
        ik.Chain(arm.offsets, limits=(None, ik.SwingTwist(swing=1.0), None, None))


def test_chain_is_a_pytree():
    arm = ik.lab_arm()
    leaves, tree = jax.tree_util.tree_flatten(arm)
    assert len(leaves) == 1 and leaves[0].shape == (5, 3)
    again = jax.tree_util.tree_unflatten(tree, leaves)
    np.testing.assert_array_equal(again.offsets, arm.offsets)


@pytest.mark.parametrize("J", [2, 7, 20])
def test_fk_matches_numpy(dtype, J):
    rng = np.random.default_rng(J)
    offsets = rng.normal(size=(J, 3))
    rots = random_unit_quaternions(rng, (J,))
    chain = ik.Chain(offsets.astype(dtype))
    pose = ik.fk(chain, rots.astype(dtype))
    P, R = numpy_fk(offsets, rots)
    assert pose.positions.dtype == dtype
    np.testing.assert_allclose(pose.positions, P, atol=30 * TOL[dtype] * J)
    R_jax = np.array([quat_to_matrix(q) for q in np.asarray(pose.rotations, np.float64)])
    np.testing.assert_allclose(R_jax, R, atol=30 * TOL[dtype] * J)


def test_fk_unrolled_equals_rolled_and_batches():
    rng = np.random.default_rng(1)
    chain = ik.Chain(rng.normal(size=(6, 3)))
    rots = random_unit_quaternions(rng, (4, 2, 6))
    a = ik.fk(chain, rots, unroll=True).positions
    b = ik.fk(chain, rots, unroll=False).positions
    assert a.shape == (4, 2, 6, 3)
    np.testing.assert_allclose(a, b, atol=1e-12)
    loop = np.stack([[ik.fk(chain, rots[i, j]).positions for j in range(2)] for i in range(4)])
    np.testing.assert_allclose(a, loop, atol=1e-12)


def test_fk_grads():
    rng = np.random.default_rng(2)
    offsets = jnp.asarray(rng.normal(size=(5, 3)))
    rots = jnp.asarray(random_unit_quaternions(rng, (5,)))

    def f(offsets, rots):
        return ik.fk(ik.Chain(offsets), rots).positions

    check_grads(f, (offsets, rots), order=1, modes=("fwd", "rev"), atol=1e-6, rtol=1e-6)


def test_default_dtype_is_float32_and_x64_gives_float64():
    code = (
        "import jax, jaxsim.ik as ik;"
        "r = ik.fabrik(ik.lab_arm(), [0.6, 0.0, 0.0]);"
        "print(r.rotations.dtype, r.error.dtype);"
        "jax.config.update('jax_enable_x64', True);"
        "r = ik.fabrik(ik.lab_arm(), [0.6, 0.0, 0.0]);"
        "print(r.rotations.dtype, r.error.dtype)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["float32", "float32", "float64", "float64"]


def test_arc_lean_matches_shortest_arc_and_is_safe_where_degenerate():
    """The batched CCD sweep's arc: the shortest arc (as ``from_two_vectors``) on generic
    pairs, accurate next to a half-turn, and the identity, with finite gradients, on zero
    and exactly opposite vectors."""
    from jaxsim._geometry import quat as _quat

    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(2, 3, 200)) * rng.uniform(0.01, 10.0, size=(2, 1, 200))
    lean = np.array(_quat.arc_lean(tuple(a), tuple(b)))
    ref = np.array(_quat.from_two_vectors(tuple(a), tuple(b)))
    np.testing.assert_allclose(lean, ref, atol=1e-12)
    # 1e-7 rad short of a half-turn: q_w = sin(1e-7 / 2) to full relative precision
    u = np.array([0.6, 0.8, 0.0])
    v = -np.cos(1e-7) * u + np.sin(1e-7) * np.array([-0.8, 0.6, 0.0])
    q = np.array(_quat.arc_lean(tuple(3.0 * u), tuple(0.5 * v)))
    np.testing.assert_allclose(q[0], np.sin(0.5e-7), rtol=1e-8)
    np.testing.assert_allclose(np.array(_quat.rotate(tuple(q), tuple(u))), v, atol=1e-15)
    # with a half-turn axis: exactly opposite -> the half-turn, 1e-7 short of it -> the arc
    axis = (jnp.array(-0.8), jnp.array(0.6), jnp.array(0.0))
    q = np.array(_quat.arc_lean(tuple(3.0 * u), tuple(-0.5 * u), axis))
    np.testing.assert_allclose(q, [0.0, -0.8, 0.6, 0.0], atol=1e-15)
    q = np.array(_quat.arc_lean(tuple(3.0 * u), tuple(0.5 * v), axis))
    np.testing.assert_allclose(np.array(_quat.rotate(tuple(q), tuple(u))), v, atol=1e-15)
    pairs = (((0.0, 0.0, 0.0), (1.0, 2.0, 3.0)), ((1.0, 2.0, 3.0), (0.0, 0.0, 0.0)),
             ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), ((1.0, -2.0, 0.5), (-2.0, 4.0, -1.0)))
    for dtype in (np.float32, np.float64):
        for x, y in pairs:
            x, y = jnp.array(x, dtype), jnp.array(y, dtype)
            q = np.array(_quat.arc_lean(tuple(x), tuple(y)))
            np.testing.assert_allclose(q, [1.0, 0.0, 0.0, 0.0], atol=2 * np.finfo(dtype).eps)
            if not (np.any(x) and np.any(y)):  # a zero vector: the identity, axis or not
                q = np.array(_quat.arc_lean(tuple(x), tuple(y), tuple(a.astype(dtype) for a in axis)))
                np.testing.assert_allclose(q, [1.0, 0.0, 0.0, 0.0], atol=2 * np.finfo(dtype).eps)
            g = jax.grad(lambda x, y: sum(c.sum() for c in _quat.arc_lean(tuple(x), tuple(y))), argnums=(0, 1))(x, y)
            assert all(np.isfinite(np.asarray(gi)).all() for gi in g)
