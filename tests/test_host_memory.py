"""``jaxsim.retain_host_memory``: argument checks, and that freed blocks stop faulting."""

import subprocess
import sys
import textwrap

import pytest

import jaxsim
from jaxsim._host_memory import _glibc

# A child process mallocs, touches and frees a 64 MiB block 5 times, before and after
# retain_host_memory(), and prints the minor page faults of each round (ctypes malloc, so
# no array library's own caching or huge-page hints are involved).
CHILD = textwrap.dedent("""
    import ctypes, resource
    import jaxsim
    libc = ctypes.CDLL("libc.so.6")
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = (ctypes.c_size_t,)
    libc.free.argtypes = (ctypes.c_void_p,)
    libc.memset.argtypes = (ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t)
    n = 64 << 20

    def faults():
        f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        for _ in range(5):
            p = libc.malloc(n)
            libc.memset(p, 1, n)
            libc.free(p)
        return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0

    before = faults()
    applied = jaxsim.retain_host_memory()
    faults()  # the first block after the change is new to the heap
    print(before, faults(), applied)
""")


@pytest.mark.parametrize("bad, err", [(1.5, TypeError), ("1GB", TypeError), (True, ValueError), (0, ValueError),
                                      (2**20 - 1, ValueError), (2**30 + 1, ValueError)])
def test_bad_limits_raise(bad, err):
    with pytest.raises(err, match="limit_bytes"):
        jaxsim.retain_host_memory(bad)


@pytest.mark.skipif(_glibc() is None, reason="glibc malloc only")
def test_freed_blocks_are_reused_without_page_faults():
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, check=True, timeout=120)
    before, after, applied = out.stdout.split()
    pages = 5 * (64 << 20) // 4096
    assert applied == "True"
    assert int(before) > 0.9 * pages  # every round faults the whole block in again
    assert int(after) < 0.01 * pages


@pytest.mark.skipif(_glibc() is not None, reason="other C libraries")
def test_no_op_elsewhere():
    assert jaxsim.retain_host_memory() is False
