"""What every benchmark case shares: the :class:`Context` it runs in and the way a compiled
program becomes a table row (timing, memory, FLOP and byte efficiency)."""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import jax

from gijax.bench.cost import cost_of, efficiency
from gijax.bench.memory import MIB, CaseMemory, compiled_memory
from gijax.bench.timing import time_call


@dataclasses.dataclass
class Context:
    """What every case needs: the suite's settings, the device, and the calibration."""

    settings: "object"  # gijax.bench.suite.SuiteSettings
    device: object
    limits: dict | None = None
    log: Callable[[str], None] = print

    @property
    def reps(self) -> int:
        return self.settings.reps

    @property
    def warmup(self) -> int:
        return self.settings.warmup


def timing_row(stats, prefix: str = "") -> dict:
    """Timing statistics as row fields in milliseconds (``ms_median``, ``ms_iqr``, ...)."""
    return stats.as_dict(prefix=f"{prefix}ms_" if prefix else "ms_", factor=1e3)


def program_row(compiled, seconds: float, limits) -> dict:
    """A compiled program's XLA memory and its FLOP / byte efficiency at ``seconds`` a call."""
    row = {}
    mem = compiled_memory(compiled)
    if mem:
        row["xla_peak_mib"] = mem["peak_bytes"] / MIB
        row["xla_temp_mib"] = mem["temp_bytes"] / MIB
    row.update(efficiency(cost_of(compiled), seconds, limits))
    return row


def measure_program(ctx: Context, build: Callable[[], tuple]) -> tuple[dict, object, tuple]:
    """Compile (timed, memory watched) and run a program; returns (row, compiled, args)."""
    with CaseMemory() as mem:
        t0 = time.perf_counter()
        compiled, args = build()
        compile_s = time.perf_counter() - t0
        jax.block_until_ready(compiled(*args))
    stats, _ = time_call(lambda: compiled(*args), warmup=max(ctx.warmup - 1, 0), reps=ctx.reps)
    row = {"compile_s": compile_s, **timing_row(stats), **mem.result(),
           **program_row(compiled, stats.median, ctx.limits)}
    return row, compiled, args
