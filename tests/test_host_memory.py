"""gijax.host_memory: freed heap memory really goes back to the system, and a process that
asks for huge pages faults far less. Each check runs in a fresh interpreter, because every
setting is process-wide."""

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


# --------------------------------------------------------------------------- huge pages

def test_huge_page_environment_adds_the_tunable_only_where_it_changes_something():
    from gijax.host_memory import huge_page_environment

    env = huge_page_environment({"GLIBC_TUNABLES": "glibc.malloc.arena_max=2", "A": "1"},
                                thp_mode="madvise", glibc_version=(2, 36))
    assert env["GLIBC_TUNABLES"] == "glibc.malloc.arena_max=2:glibc.malloc.hugetlb=1"
    assert env["A"] == "1"
    assert huge_page_environment({}, "madvise", (2, 35))["GLIBC_TUNABLES"] == \
        "glibc.malloc.hugetlb=1"
    for environ, mode, version in (
            ({"GIJAX_HUGE_PAGES": "0"}, "madvise", (2, 36)),            # opted out
            ({"GLIBC_TUNABLES": "glibc.malloc.hugetlb=0"}, "madvise", (2, 36)),  # user's own
            ({}, "always", (2, 36)), ({}, "never", (2, 36)),
            ({}, "madvise", (2, 34))):
        assert huge_page_environment(environ, mode, version) is None, (environ, mode, version)


def test_transparent_huge_page_mode_reads_the_bracketed_word(tmp_path):
    from gijax.host_memory import transparent_huge_page_mode

    (tmp_path / "enabled").write_text("always [madvise] never\n")
    assert transparent_huge_page_mode(str(tmp_path / "enabled")) == "madvise"
    assert transparent_huge_page_mode(str(tmp_path / "missing")) is None


# A 256 MB buffer allocated with the C library's malloc, touched and freed eight times, the way
# XLA's CPU runtime treats each execution's temporaries (numpy would not do: it asks for huge
# pages itself); prints minor page faults per round and the tunables seen.
FAULTS = textwrap.dedent("""
    import ctypes, os, resource
    from gijax.host_memory import use_huge_pages, _glibc
    use_huge_pages()
    libc = _glibc()
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    def faults():
        return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    def round():
        block = libc.malloc(1 << 28)
        ctypes.memset(block, 1, 1 << 28)
        libc.free(block)
    round()
    f0 = faults()
    for _ in range(8):
        round()
    print((faults() - f0) / 8, os.environ.get("GLIBC_TUNABLES", "-"))
""")


def _faults(switch: str) -> tuple[float, str]:
    import os

    env = dict(os.environ, GIJAX_HUGE_PAGES=switch)
    env.pop("GLIBC_TUNABLES", None)
    out = subprocess.run([sys.executable, "-c", FAULTS], capture_output=True, text=True,
                         check=True, env=env).stdout.split()
    return float(out[0]), out[1]


def test_use_huge_pages_reexecutes_once_and_cuts_page_faults():
    from gijax.host_memory import huge_page_environment

    if huge_page_environment({}) is None:
        pytest.skip("the kernel's huge pages are not in 'madvise' mode, or glibc < 2.35")
    plain, tunables = _faults("0")
    assert tunables == "-"
    huge, tunables = _faults("1")
    assert tunables == "glibc.malloc.hugetlb=1"      # set once, not appended per exec
    assert plain > 60_000                             # 4 KB pages: 65 536 per round
    assert huge < plain / 20, (plain, huge)          # 2 MB pages: about 128


def test_the_command_line_entry_runs_once_under_the_tunable():
    code = ("import sys; sys.argv = ['gijax', '--version']\n"
            "import os; print(os.environ.get('GLIBC_TUNABLES', '-'))\n"
            "from gijax.cli import run; run()")
    import os

    env = {k: v for k, v in os.environ.items() if k not in ("GLIBC_TUNABLES", "GIJAX_HUGE_PAGES")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env=env).stdout.split("\n")
    from gijax.host_memory import huge_page_environment

    if huge_page_environment({}) is None:
        assert out[0] == "-" and out[1].startswith("gijax "), out
    else:
        # The first process prints, re-executes once, and the second runs the command.
        assert out[:2] == ["-", "glibc.malloc.hugetlb=1"] and out[2].startswith("gijax "), out
