"""The C library's heap, for processes that care about their resident memory.

glibc keeps memory that a program frees in its heap for reuse instead of returning it to the
system, and it raises its mmap threshold after the first large free, so later large buffers
come from that heap too. A process that builds a paper-size network (random initialisation,
compiled init programs) and compiles its forward frees several hundred MB that it will not
reuse in the same shapes, yet keeps them resident. Two remedies, both process-wide and both
without effect on results:

* :func:`release_freed_memory` hands freed heap memory back now (``malloc_trim``); cheap, and
  called by :func:`gijax.store.load_model` after it builds a model;
* :func:`fix_mmap_threshold` keeps every allocation above a size mapped (freed straight back to
  the system), at the cost of faulting those buffers in afresh each time: the ``'low'`` memory
  profile of :mod:`gijax.export.ort_session`.

Both do nothing (and return False) where the C library is not glibc. This module imports only
the standard library.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import sys

# malloc.h: M_MMAP_THRESHOLD = -3.
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 1 << 20


@functools.lru_cache(maxsize=1)
def _glibc():
    if not sys.platform.startswith("linux"):
        return None
    name = ctypes.util.find_library("c")
    if not name:
        return None
    try:
        libc = ctypes.CDLL(name)
    except OSError:
        return None
    needed = ("gnu_get_libc_version", "malloc_trim", "mallopt")
    return libc if all(hasattr(libc, f) for f in needed) else None


def release_freed_memory() -> bool:
    """Return the heap's free memory to the system (``malloc_trim(0)``); True when glibc did."""
    libc = _glibc()
    return bool(libc is not None and libc.malloc_trim(0))


def fix_mmap_threshold(nbytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Fix glibc's mmap threshold at ``nbytes`` for the rest of this process (allocations at
    least this large are mapped and unmapped when freed); True when set."""
    libc = _glibc()
    return bool(libc is not None and libc.mallopt(_M_MMAP_THRESHOLD, int(nbytes)))


__all__ = ["MMAP_THRESHOLD_BYTES", "fix_mmap_threshold", "release_freed_memory"]
