"""Benchmark toolkit: timing statistics, memory, cost analysis and calibration, machine
information, JSON / Markdown reports, and the suite behind ``gijax bench``."""

import importlib

# Names load on first use (PEP 562): a child process of gijax.bench.isolated that runs only
# onnxruntime must be able to import this package without importing JAX.
_HOMES = {
    "cost": ("cost_of", "efficiency", "matmul_peak", "memory_bandwidth"),
    "machine": ("git_revision", "machine_info"),
    "memory": ("CaseMemory", "PeakRSS", "compiled_memory", "device_memory", "device_peak_mib",
               "host_peak_rss_mib", "rss_bytes"),
    "report": ("markdown_grid", "markdown_table", "text_table", "write_json", "write_text"),
    "timing": ("Stats", "block", "linear_increment", "paired_ratio", "timing_stats",
               "time_alternating", "time_call"),
}
_HOME_OF = {name: module for module, names in _HOMES.items() for name in names}


def __getattr__(name):
    if name in _HOME_OF:
        return getattr(importlib.import_module(f"gijax.bench.{_HOME_OF[name]}"), name)
    raise AttributeError(f"module 'gijax.bench' has no attribute {name!r}")


__all__ = [
    "CaseMemory", "PeakRSS", "Stats", "block", "compiled_memory", "cost_of", "device_memory",
    "device_peak_mib", "efficiency", "git_revision", "host_peak_rss_mib", "linear_increment",
    "machine_info", "markdown_grid", "markdown_table",
    "matmul_peak", "memory_bandwidth", "paired_ratio", "rss_bytes", "timing_stats", "text_table",
    "time_alternating", "time_call", "write_json", "write_text",
]
