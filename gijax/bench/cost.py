"""FLOPs and memory traffic from XLA's cost analysis, and the machine's measured limits.

``compiled.cost_analysis()`` counts the floating-point operations of every HLO instruction
(a matmul of (M, K) by (K, N) counts 2 M N K; convolutions likewise) and the bytes each
instruction reads and writes. The bytes are those of the optimised program, after fusion, so
they approximate the traffic to memory (a fused chain counts its inputs and outputs once).

The limits are measured in the same run, on the same device and dtype:

* peak FLOP/s: a large square float32 matmul (the best case for the machine's math units);
* memory bandwidth: a large array copy (``x + 1``: read and write every byte) and a reduction
  (``sum(x)``: read every byte), in bytes moved per second.

A figure's efficiency is then achieved / limit, and its roofline bound
``max(flops / peak, bytes / bandwidth)`` is the time it could take at best.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

from gijax.bench.timing import time_call


def cost_of(compiled) -> dict:
    """``flops``, ``bytes_accessed`` and ``transcendentals`` of a compiled program (floats;
    0.0 for a quantity XLA did not report)."""
    cost = compiled.cost_analysis()
    if isinstance(cost, (list, tuple)):  # older JAX: one dict per device program
        cost = cost[0] if cost else {}
    cost = cost or {}
    return {"flops": float(cost.get("flops", 0.0)),
            "bytes_accessed": float(cost.get("bytes accessed", 0.0)),
            "transcendentals": float(cost.get("transcendentals", 0.0))}


def compile_fn(fn: Callable, *args, **jit_kwargs):
    """``jax.jit(fn, **jit_kwargs).lower(*args).compile()``: the compiled program."""
    return jax.jit(fn, **jit_kwargs).lower(*args).compile()


def matmul_peak(n: int = 1024, reps: int = 5, warmup: int = 1, dtype=jnp.float32,
                device=None) -> dict:
    """Measured FLOP/s of an (n, n) @ (n, n) matmul.

    Returns the FLOPs per call (2 n^3, checked against XLA's count), the median and best times
    (s), and ``flops_per_s`` from the best time (the machine's demonstrated peak; the median is
    also given as ``flops_per_s_median``).
    """
    key = jax.random.PRNGKey(0)
    a = jax.device_put(jax.random.normal(key, (n, n), dtype), device)
    b = jax.device_put(jax.random.normal(jax.random.fold_in(key, 1), (n, n), dtype), device)
    compiled = compile_fn(lambda x, y: x @ y, a, b)
    flops = 2.0 * n**3
    xla_flops = cost_of(compiled)["flops"]
    stats, _ = time_call(lambda: compiled(a, b), warmup=warmup, reps=reps)
    return {"n": n, "dtype": jnp.dtype(dtype).name, "flops": flops, "xla_flops": xla_flops,
            "median_s": stats.median, "min_s": stats.min, "iqr_s": stats.iqr,
            "flops_per_s": flops / stats.min, "flops_per_s_median": flops / stats.median}


def memory_bandwidth(mib: int = 128, reps: int = 5, warmup: int = 1, device=None) -> dict:
    """Measured bytes/s of a float32 array of ``mib`` MiB: copy (``x + 1``, read + write) and
    reduce (``sum(x)``, read). ``bytes_per_s`` is the better of the two (best times)."""
    n = int(mib) * 2**20 // 4
    x = jax.device_put(jnp.arange(n, dtype=jnp.float32), device)
    nbytes = 4.0 * n
    # The copy updates its input in place (donated): a fresh output buffer would add the
    # kernel's first-touch page faults, which are not memory bandwidth.
    copy = compile_fn(lambda v: v + 1.0, x, donate_argnums=0)
    reduce = compile_fn(lambda v: jnp.sum(v), x)
    r_stats, _ = time_call(lambda: reduce(x), warmup=warmup, reps=reps)
    holder = {"x": x}

    def copy_once():
        holder["x"] = copy(holder["x"])
        return holder["x"]

    c_stats, _ = time_call(copy_once, warmup=warmup, reps=reps)
    copy_bps = 2.0 * nbytes / c_stats.min
    reduce_bps = nbytes / r_stats.min
    return {"mib": int(mib), "copy_bytes_per_s": copy_bps, "reduce_bytes_per_s": reduce_bps,
            "copy_median_s": c_stats.median, "reduce_median_s": r_stats.median,
            "copy_xla_bytes": cost_of(copy)["bytes_accessed"],
            "reduce_xla_bytes": cost_of(reduce)["bytes_accessed"],
            "bytes_per_s": max(copy_bps, reduce_bps)}


def efficiency(cost: dict, seconds: float, limits: dict | None) -> dict:
    """Achieved FLOP/s and bytes/s of a program that took ``seconds``, and, given ``limits``
    (``flops_per_s``, ``bytes_per_s``), the fractions of those limits and the roofline bound
    (the least time the program could take on this machine, s)."""
    out = {"gflop": cost["flops"] / 1e9, "gbytes": cost["bytes_accessed"] / 1e9,
           "gflops_per_s": cost["flops"] / seconds / 1e9,
           "gbytes_per_s": cost["bytes_accessed"] / seconds / 1e9}
    if cost["bytes_accessed"] > 0:
        out["flops_per_byte"] = cost["flops"] / cost["bytes_accessed"]
    if limits:
        peak, bw = limits["flops_per_s"], limits["bytes_per_s"]
        out["frac_peak_flops"] = cost["flops"] / seconds / peak
        out["frac_bandwidth"] = cost["bytes_accessed"] / seconds / bw
        bound = max(cost["flops"] / peak, cost["bytes_accessed"] / bw)
        out["roofline_s"] = bound
        out["frac_roofline"] = bound / seconds
    return out
