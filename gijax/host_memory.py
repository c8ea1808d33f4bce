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

Both do nothing (and return False) where the C library is not glibc.

Transparent huge pages. XLA's CPU runtime allocates each execution's temporaries afresh, and
glibc serves buffers above its mmap threshold (32 MB at most) with fresh mappings, so every
training step faults its working set in again, 4 KB at a time: about 150 000 page faults and
0.3-0.4 CPU seconds of kernel time per ``G16VV-cpu`` step at batch 8 on this project's 2-core
machines. Where the kernel hands out huge pages on request (``madvise`` mode) glibc asks for
them when its ``glibc.malloc.hugetlb=1`` tunable is set, and the same step faults about 800
times. A tunable is read only when a process starts, so :func:`use_huge_pages` re-executes
the process with it set: the ``gijax`` command line and the experiment and benchmark scripts
call it first thing. Child processes inherit it (a benchmark's PyTorch peer included).
``GIJAX_HUGE_PAGES=0`` leaves the allocator as it is. Results do not change; only where pages
come from.

This module imports only the standard library.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
import sys

# malloc.h: M_MMAP_THRESHOLD = -3.
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 1 << 20

HUGE_PAGE_TUNABLE = "glibc.malloc.hugetlb"
HUGE_PAGES_SWITCH = "GIJAX_HUGE_PAGES"          # '0': leave the allocator as it is
THP_MODE_FILE = "/sys/kernel/mm/transparent_hugepage/enabled"
_TUNABLE_SINCE = (2, 35)                          # glibc release that reads the tunable


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


def transparent_huge_page_mode(path: str = THP_MODE_FILE) -> str | None:
    """The kernel's transparent-huge-page mode ('always', 'madvise' or 'never'; the bracketed
    word of ``path``), or None where the file is missing or unreadable."""
    try:
        with open(path, encoding="ascii") as f:
            text = f.read()
    except OSError:
        return None
    start, end = text.find("["), text.find("]")
    return text[start + 1:end] if 0 <= start < end else None


def _glibc_version() -> tuple[int, ...] | None:
    libc = _glibc()
    if libc is None:
        return None
    libc.gnu_get_libc_version.restype = ctypes.c_char_p
    try:
        return tuple(int(p) for p in libc.gnu_get_libc_version().decode().split(".")[:2])
    except ValueError:
        return None


def huge_page_environment(environ: dict | None = None, thp_mode: str | None = None,
                          glibc_version: tuple[int, ...] | None = None) -> dict | None:
    """The environment that makes glibc ask for transparent huge pages: ``environ`` (default
    this process's) with ``glibc.malloc.hugetlb=1`` added to ``GLIBC_TUNABLES`` (other
    tunables kept), or None when it would change nothing: opted out (``GIJAX_HUGE_PAGES=0``),
    already set, a kernel mode other than 'madvise' ('always' gives huge pages anyway, 'never'
    none), or a C library other than glibc 2.35 or newer. ``thp_mode`` and ``glibc_version``
    default to this machine's."""
    environ = dict(os.environ if environ is None else environ)
    if environ.get(HUGE_PAGES_SWITCH, "1").strip() == "0":
        return None
    tunables = environ.get("GLIBC_TUNABLES", "")
    if any(t.split("=")[0] == HUGE_PAGE_TUNABLE for t in tunables.split(":") if t):
        return None
    mode = transparent_huge_page_mode() if thp_mode is None else thp_mode
    version = _glibc_version() if glibc_version is None else glibc_version
    if mode != "madvise" or version is None or version < _TUNABLE_SINCE:
        return None
    environ["GLIBC_TUNABLES"] = ":".join(t for t in (tunables, f"{HUGE_PAGE_TUNABLE}=1") if t)
    return environ


def use_huge_pages() -> None:
    """Re-execute this process (the same interpreter, options and arguments) with
    :func:`huge_page_environment`, when that changes anything; else return at once. Call it
    first thing in a program's entry point, before it has done anything a restart would repeat
    or lose; never from library code. A failed ``exec`` leaves the process running as it was."""
    env = huge_page_environment()
    if env is None or not sys.executable or not getattr(sys, "orig_argv", None):
        return
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        os.execve(sys.executable, [sys.executable, *sys.orig_argv[1:]], env)
    except OSError:
        return


__all__ = ["HUGE_PAGES_SWITCH", "HUGE_PAGE_TUNABLE", "MMAP_THRESHOLD_BYTES",
           "fix_mmap_threshold", "huge_page_environment", "release_freed_memory",
           "transparent_huge_page_mode", "use_huge_pages"]
