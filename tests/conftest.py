"""Test configuration: x64 is on so float64 cross-checks are possible.

Tests that exercise float32 build their inputs in float32 explicitly; jaxsim keeps the
dtype of the scene it is given, so both precisions run in one session.  The float32
*default* (x64 off) is checked in a subprocess.
"""

import os
import tempfile

os.environ.setdefault("MPLBACKEND", "Agg")
# A persistent compilation cache per test process, inherited by the subprocesses and
# notebook kernels that process starts (it waits for them), so identical programs compile
# once.  Never one folder for two concurrent processes: JAX writes cache entries without a
# lock, and a process that reads an entry while another is still writing it aborts.
os.environ.setdefault(
    "JAX_COMPILATION_CACHE_DIR",
    os.path.join(tempfile.gettempdir(), "jaxsim-test-jax-cache-" + os.environ.get("PYTEST_XDIST_WORKER", "main")),
)

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
# Run each computation before the next one is traced or compiled: no program executes on
# the CPU thread pool while another one compiles (test processes only; the library keeps
# JAX's default asynchronous dispatch).
jax.config.update("jax_cpu_enable_async_dispatch", False)

#: Tests that take the longest, started first so the workers finish together.
SLOW_FIRST = ("test_report.py", "test_notebooks.py", "test_sharding.py", "test_cli.py", "test_cloth_stability.py")


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
