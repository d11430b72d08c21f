"""Test configuration: x64 is on so float64 cross-checks are possible.

Tests that exercise float32 build their inputs in float32 explicitly; jaxsim keeps the
dtype of the scene it is given, so both precisions run in one session.  The float32
*default* (x64 off) is checked in a subprocess.
"""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
# No persistent compilation cache in this process or in the subprocesses and notebook
# kernels it starts: every test run starts cold, as on a fresh machine.
os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)

#: Each live compiled XLA:CPU program holds about six memory mappings, and Linux caps a
#: process at ``vm.max_map_count`` (65530 by default): a test worker that keeps every
#: program of half the suite alive crashes inside XLA (segfault or abort) when it hits
#: the cap.  Compiled programs are dropped after every test module, and mid-module when a
#: process nears the cap.
MAP_GUARD = 40000


def _mappings() -> int:
    try:
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


def _drop_compiled_programs():
    import gc

    jax.clear_caches()
    gc.collect()


@pytest.fixture(autouse=True, scope="module")
def _fresh_compilation_caches_per_module():
    yield
    _drop_compiled_programs()


@pytest.fixture(autouse=True)
def _guard_memory_mappings():
    yield
    if _mappings() > MAP_GUARD:
        _drop_compiled_programs()


#: Tests that take the longest, started first so the workers finish together.
SLOW_FIRST = ("test_report.py", "test_notebooks.py", "test_sharding.py", "test_cli.py", "test_cloth_contact.py",
              "test_cloth_stability.py")


def pytest_collection_modifyitems(items):
    rank = {name: k for k, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda it: rank.get(os.path.basename(str(it.fspath)), len(SLOW_FIRST)))



@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request):
    return np.dtype(request.param)
