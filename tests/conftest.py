"""Test configuration: x64 is on so float64 cross-checks are possible.

Tests that exercise float32 build their inputs in float32 explicitly; jaxsim keeps the
dtype of the scene it is given, so both precisions run in one session.  The float32
*default* (x64 off) is checked in a subprocess.
"""

import os
import shutil
import tempfile

os.environ.setdefault("MPLBACKEND", "Agg")
#: One persistent compilation cache per test run, made empty by the controlling process
#: and removed when it ends: the xdist workers and the subprocesses and notebook kernels
#: they start inherit it, so a program compiled once in the run (by another worker, by a
#: module before the per-module drop below, or by a CLI subprocess) is loaded, not
#: compiled again.  Every run starts cold, as on a fresh machine; the user's own cache
#: (``~/.cache/jaxsim``) is never read.
if "PYTEST_XDIST_WORKER" not in os.environ:
    RUN_CACHE = tempfile.mkdtemp(prefix="jaxsim-tests-jax-cache-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = RUN_CACHE
    os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0.5"
else:
    RUN_CACHE = None

#: This process's XLA:CPU compiles with LLVM at -O0 and XLA's legacy fusion emitters
#: (``_compile_flags``): the program's math is the one users get, only its machine code is
#: slower, and the suite's small programs are compile-bound (a cloth step compiles 2x, the
#: humanoid's tree kernel 1.5x faster).  The flags are read once, at the first compile;
#: the environment is restored after it.  The subprocess tests (the CLI demo and report,
#: the notebooks, the sharding check) take the same flags (``with_fast_compile``); a test
#: that compares two programs bit for bit compiles them with XLA's defaults
#: (``_helpers.as_users_compile``).
from _compile_flags import FAST_COMPILE_FLAGS  # noqa: E402

_XLA_FLAGS = os.environ.get("XLA_FLAGS")
os.environ["XLA_FLAGS"] = ((_XLA_FLAGS or "") + " " + FAST_COMPILE_FLAGS).strip()

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

pytest_plugins = ["_compile_stats"]

jax.jit(lambda x: x + 1)(0).block_until_ready()
if _XLA_FLAGS is None:
    del os.environ["XLA_FLAGS"]
else:
    os.environ["XLA_FLAGS"] = _XLA_FLAGS
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)

#: Each live compiled XLA:CPU program holds about six memory mappings, and Linux caps a
#: process at ``vm.max_map_count`` (65530 by default): a test worker that keeps every
#: program of half the suite alive crashes inside XLA (segfault or abort) when it hits
#: the cap.  Compiled programs are dropped when a process nears the cap (and kept
#: otherwise: a later module that compiles the same program, or the same small eager
#: operation, finds it in memory).
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


@pytest.fixture(autouse=True)
def _guard_memory_mappings():
    yield
    if _mappings() > MAP_GUARD:
        _drop_compiled_programs()


#: The test files that take the longest (worker-seconds, 2 workers, 2026-12-05: notebooks 116,
#: limits 104, trust 98, tree 95, report 95, BDF2 92, IK solvers 91, ...), longest first: with
#: ``--no-loadscope-reorder`` (pyproject) xdist hands out files in this order, so the
#: single-test subprocess files (the report, the sharding check) do not start last while
#: the other worker idles (xdist's default order is by test count, which put them at the end).
SLOW_FIRST = ("test_notebooks.py", "test_report.py", "test_cloth_self_contact.py", "test_ik_limits.py", "test_cloth_trust.py", "test_ik_tree.py",
              "test_cloth_bdf2.py", "test_ik_solvers.py", "test_differentiable.py", "test_cloth_contact.py",
              "test_cloth_character.py", "test_cloth_wind.py", "test_cloth_pins.py",
              "test_cloth_stability.py", "test_cloth_start.py", "test_cli.py", "test_sharding.py",
              "test_cloth_stencil.py", "test_cloth_coarse.py", "test_input_sweep.py", "test_cloth_substeps.py",
              "test_cloth_core.py")


def pytest_collection_modifyitems(items):
    rank = {name: k for k, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda it: rank.get(os.path.basename(str(it.fspath)), len(SLOW_FIRST)))



def pytest_unconfigure(config):
    if RUN_CACHE is not None:
        shutil.rmtree(RUN_CACHE, ignore_errors=True)


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request):
    return np.dtype(request.param)
