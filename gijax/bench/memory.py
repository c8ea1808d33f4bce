"""Peak memory of a benchmark case.

* XLA's own accounting of a compiled program (``compiled.memory_analysis()``): arguments +
  outputs + temporaries - aliased bytes, the memory the executable needs at its peak. The same
  figure on every backend, and exact for that program.
* On a GPU, the device allocator's statistics (``jax.local_devices()[0].memory_stats()``):
  ``bytes_in_use`` and ``peak_bytes_in_use`` (a process-wide high-water mark that never goes
  down, so a case's own peak is only known when it raised the mark).
* On the CPU, the process's resident set (RSS), polled in a thread while the case runs;
  freed heap pages are handed back to the OS first (``malloc_trim``) so that a case does not
  hide its growth in memory an earlier case freed.
* For a whole command (``gijax eval``, the experiments): the process's resident-set
  high-water mark and the device allocator's.
"""

from __future__ import annotations

import ctypes
import threading
import time

MIB = 2**20


def rss_bytes() -> int:
    """Resident set size of this process, bytes."""
    import psutil

    return int(psutil.Process().memory_info().rss)


def trim_heap() -> None:
    """Return freed heap memory to the OS (glibc); a no-op where there is no malloc_trim."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


class PeakRSS:
    """Context manager: the largest RSS growth over the entry value while the block runs.

    ``interval`` seconds between polls (short allocations between two polls can be missed;
    the final value is always sampled). After exit ``growth_bytes`` and ``peak_bytes`` hold the
    results.
    """

    def __init__(self, interval: float = 0.002):
        self.interval = interval
        self.start_bytes = 0
        self.peak_bytes = 0
        self._stop = threading.Event()
        self._thread = None

    def _poll(self) -> None:
        while not self._stop.is_set():
            self.peak_bytes = max(self.peak_bytes, rss_bytes())
            time.sleep(self.interval)

    def __enter__(self) -> "PeakRSS":
        trim_heap()
        self.start_bytes = self.peak_bytes = rss_bytes()
        self._stop.clear()
        self._thread = threading.Thread(target=self._poll, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.peak_bytes = max(self.peak_bytes, rss_bytes())

    @property
    def growth_bytes(self) -> int:
        return self.peak_bytes - self.start_bytes


def compiled_memory(compiled) -> dict:
    """XLA's memory accounting of a compiled program, bytes (empty dict when unavailable).

    ``peak_bytes`` is arguments + outputs + temporaries - aliased bytes. Where the backend
    reports it, ``reported_peak_bytes`` is XLA's own figure from its heap simulation of the
    program's buffers, which can be lower (buffers whose lifetimes do not overlap share it).
    """
    try:
        mem = compiled.memory_analysis()
    except (AttributeError, NotImplementedError, RuntimeError):
        return {}
    if mem is None:
        return {}
    args = int(mem.argument_size_in_bytes)
    out = int(mem.output_size_in_bytes)
    temp = int(mem.temp_size_in_bytes)
    alias = int(mem.alias_size_in_bytes)
    result = {"argument_bytes": args, "output_bytes": out, "temp_bytes": temp,
              "alias_bytes": alias, "peak_bytes": args + out + temp - alias,
              "code_bytes": int(mem.generated_code_size_in_bytes)}
    reported = int(getattr(mem, "peak_memory_in_bytes", 0) or 0)
    if reported:
        result["reported_peak_bytes"] = reported
    return result


def host_peak_rss_mib() -> float:
    """The process's resident-set high-water mark since it started, MiB.

    Linux's ``VmHWM`` belongs to the process image since its ``exec``; ``ru_maxrss`` (the
    fallback elsewhere) would also count the parent's memory at the fork that started a child.
    """
    import resource

    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def device_memory(device=None) -> dict:
    """The accelerator allocator's statistics (bytes_in_use, peak_bytes_in_use, ...), or an
    empty dict on a backend without them (the CPU)."""
    import jax

    dev = jax.local_devices()[0] if device is None else device
    stats = dev.memory_stats()
    return {} if stats is None else {k: int(v) for k, v in stats.items()
                                     if isinstance(v, (int, float))}


def device_peak_mib(device=None) -> float | None:
    """The accelerator allocator's high-water mark (``peak_bytes_in_use``), MiB; None on a
    backend that reports none (the CPU)."""
    peak = device_memory(device).get("peak_bytes_in_use")
    return None if peak is None else peak / MIB


class CaseMemory:
    """Measure one case's memory with whatever the backend offers (see the module docstring).

    Use as a context manager around building and the first runs; ``result()`` returns a dict
    with ``rss_growth_mib`` (CPU), ``device_peak_mib`` and ``device_in_use_mib`` (GPU, when the
    case raised the high-water mark, else None).
    """

    def __init__(self):
        self._rss = PeakRSS()
        self._before = {}
        self._after = {}

    def __enter__(self) -> "CaseMemory":
        self._before = device_memory()
        self._rss.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self._rss.__exit__(*exc)
        self._after = device_memory()

    def result(self) -> dict:
        out = {"rss_growth_mib": self._rss.growth_bytes / MIB,
               "rss_peak_mib": self._rss.peak_bytes / MIB}
        if self._after:
            before = self._before.get("peak_bytes_in_use", 0)
            peak = self._after.get("peak_bytes_in_use", 0)
            out["device_peak_mib"] = peak / MIB if peak > before else None
            out["device_in_use_mib"] = self._after.get("bytes_in_use", 0) / MIB
        return out
