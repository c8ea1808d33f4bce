"""Benchmark toolkit: timing statistics, memory, cost analysis and calibration, machine
information, JSON / Markdown reports, and the suite behind ``gijax bench``."""

from gijax.bench.cost import cost_of, efficiency, matmul_peak, memory_bandwidth
from gijax.bench.machine import git_revision, machine_info
from gijax.bench.memory import (CaseMemory, PeakRSS, compiled_memory, device_memory,
                                device_peak_mib, host_peak_rss_mib, rss_bytes)
from gijax.bench.report import markdown_grid, markdown_table, text_table, write_json, write_text
from gijax.bench.timing import (Stats, block, linear_increment, paired_ratio, summarize,
                                time_alternating, time_call)

__all__ = [
    "CaseMemory", "PeakRSS", "Stats", "block", "compiled_memory", "cost_of", "device_memory",
    "device_peak_mib", "efficiency", "git_revision", "host_peak_rss_mib", "linear_increment",
    "machine_info", "markdown_grid", "markdown_table",
    "matmul_peak", "memory_bandwidth", "paired_ratio", "rss_bytes", "summarize", "text_table",
    "time_alternating", "time_call", "write_json", "write_text",
]
