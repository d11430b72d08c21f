import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from conftest import TOL, random_unit_quaternions
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
        (np.array([[0, 0, 0], [0, 1.0, 0], [0, 0, 0]]), "zero-length"),
    ],
)
def test_chain_rejects_bad_offsets(offsets, match):
    with pytest.raises(ValueError, match=match):
        ik.Chain(offsets)


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
