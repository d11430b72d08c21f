"""Test configuration: x64 is on so float64 cross-checks are possible.

Tests that exercise float32 build their inputs in float32 explicitly; jaxsim keeps the
dtype of the scene it is given, so both precisions run in one session.  The float32
*default* (x64 off) is checked in a subprocess.
"""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
# No persistent compilation cache, in this process or in the subprocesses and notebook
# kernels it starts: with jaxlib 0.10.2 on CPU, writing or reading a cache entry crashed a
# test process now and then (segmentation fault or abort inside JAX's cache code).
os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)

#: Tests that take the longest, started first so the workers finish together.
SLOW_FIRST = ("test_report.py", "test_notebooks.py", "test_sharding.py", "test_cli.py", "test_cloth_contact.py",
              "test_cloth_stability.py")


def pytest_collection_modifyitems(items):
    rank = {name: k for k, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda it: rank.get(os.path.basename(str(it.fspath)), len(SLOW_FIRST)))


#: Tolerances per dtype for quantities of order one.
TOL = {np.dtype(np.float32): 1e-5, np.dtype(np.float64): 1e-10}


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request):
    return np.dtype(request.param)


def random_unit_quaternions(rng, shape):
    q = rng.normal(size=shape + (4,))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)
