"""Test configuration: x64 is on so float64 cross-checks are possible.

Tests that exercise float32 build their inputs in float32 explicitly; jaxsim keeps the
dtype of the scene it is given, so both precisions run in one session.  The float32
*default* (x64 off) is checked in a subprocess.
"""

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)

#: Tolerances per dtype for quantities of order one.
TOL = {np.dtype(np.float32): 1e-5, np.dtype(np.float64): 1e-10}


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request):
    return np.dtype(request.param)


def random_unit_quaternions(rng, shape):
    q = rng.normal(size=shape + (4,))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)
