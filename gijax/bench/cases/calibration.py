"""The calibration every run starts with: the device's measured matmul FLOP/s and memory
bandwidth, the limits every efficiency figure is measured against."""

from __future__ import annotations

from gijax.bench.cases.context import Context
from gijax.bench.cost import matmul_peak, memory_bandwidth


def calibrate(ctx: Context) -> dict:
    """Measured matmul FLOP/s and memory bandwidth of the device (the limits of every figure)."""
    s = ctx.settings
    mm = matmul_peak(s.matmul_n, reps=max(ctx.reps, 5), device=ctx.device)
    bw = memory_bandwidth(s.bandwidth_mib, reps=max(ctx.reps, 5), device=ctx.device)
    ctx.limits = {"flops_per_s": mm["flops_per_s"], "bytes_per_s": bw["bytes_per_s"]}
    ctx.log(f"calibration: matmul {mm['flops_per_s'] / 1e9:.1f} GFLOP/s (n={mm['n']}), "
            f"bandwidth {bw['bytes_per_s'] / 1e9:.1f} GB/s")
    return {"matmul": mm, "bandwidth": bw, "limits": dict(ctx.limits),
            "rows": [{"what": f"matmul {mm['n']}^3 float32", "ms_median": 1e3 * mm["median_s"],
                      "ms_min": 1e3 * mm["min_s"], "gflops_per_s": mm["flops_per_s"] / 1e9,
                      "check": f"XLA flops {mm['xla_flops']:.3g} = 2n^3 {mm['flops']:.3g}"},
                     {"what": f"copy {bw['mib']} MiB", "ms_median": 1e3 * bw["copy_median_s"],
                      "gbytes_per_s": bw["copy_bytes_per_s"] / 1e9,
                      "check": f"XLA bytes {bw['copy_xla_bytes']:.3g}"},
                     {"what": f"sum {bw['mib']} MiB", "ms_median": 1e3 * bw["reduce_median_s"],
                      "gbytes_per_s": bw["reduce_bytes_per_s"] / 1e9,
                      "check": f"XLA bytes {bw['reduce_xla_bytes']:.3g}"}]}
