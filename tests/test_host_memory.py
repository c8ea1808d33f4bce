"""gijax.host_memory: freed heap memory really goes back to the system. Each check runs in a
fresh interpreter, because both settings are process-wide."""

import subprocess
import sys
import textwrap

import pytest

from gijax.host_memory import _glibc

pytestmark = pytest.mark.skipif(_glibc() is None, reason="needs glibc (Linux)")

# Resident set (statm) in MB; blocks allocated with the C library's malloc, touched, freed.
PRELUDE = textwrap.dedent("""
    import ctypes, os, sys
    from gijax import host_memory
    libc = host_memory._glibc()
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    libc.sbrk.restype = ctypes.c_void_p
    libc.sbrk.argtypes = [ctypes.c_ssize_t]
    def rss_mb():
        return int(open('/proc/self/statm').read().split()[1]) * os.sysconf('SC_PAGE_SIZE') / 1e6
    pins = []
    def churn(size, count):
        # Each block is followed by a small one that stays: freed blocks are holes in the heap
        # that cannot merge into its top, which glibc would trim by itself.
        blocks = []
        for _ in range(count):
            blocks.append(libc.malloc(size))
            ctypes.memset(blocks[-1], 1, size)   # touch every page
            # Small free fragments are used up first; a mapped block (above the heap) needs none.
            while blocks[-1] < libc.sbrk(0):
                pins.append(libc.malloc(64))
                if pins[-1] > blocks[-1]:
                    break
        held = rss_mb()
        for b in blocks:
            libc.free(b)
        return held
    base = rss_mb()
""")


def _run(body: str) -> list[float]:
    out = subprocess.run([sys.executable, "-c", PRELUDE + textwrap.dedent(body)],
                         capture_output=True, text=True, check=True).stdout
    return [float(x) for x in out.split()]


def test_release_freed_memory_returns_the_heap():
    # Only malloc_trim gives the freed, pinned blocks back.
    held, freed, trimmed = _run("""
        held = churn(100_000, 2000)
        freed = rss_mb()
        assert host_memory.release_freed_memory()
        print(held - base, freed - base, rss_mb() - base)
    """)
    assert held > 180                   # the 200 MB were resident
    assert freed > 150                  # and stay so after free, without a trim
    assert trimmed < 40                 # handed back by the trim


def test_fixed_mmap_threshold_frees_large_blocks_at_once():
    # After one large free glibc raises its threshold, so the next 2 MB blocks come from the
    # heap and stay resident; with the threshold fixed they are mapped and go back at free.
    for fixed, expect_kept in ((False, True), (True, False)):
        held, after = _run(f"""
            if {fixed}:
                assert host_memory.fix_mmap_threshold()
            churn(10_000_000, 1)   # one large free raises a dynamic threshold (up to 32 MB)
            held = churn(2_000_000, 100)
            print(held - base, rss_mb() - base)
        """)
        assert held > 180
        assert (after > 150) == expect_kept, (fixed, held, after)
