"""onnxruntime sessions for exported gijax files, without JAX.

This module imports only onnxruntime (and the standard library), so a deployment process that
runs an exported file does not pay for JAX: ``from gijax.export.ort_session import
make_session`` is the whole dependency.

Three memory profiles (``memory=``). Measured on the paper-size G16VV export (204 MB file),
quiet 2-core CPU, one forward from raw 1024 x 1024 fisheyes, peak resident set of a process
that imports onnxruntime and not JAX (``benchmarks/RESULTS.md`` has the full table):

==========  =========  ==========
profile     s/forward  peak GB
==========  =========  ==========
default     3.9        3.0
lean        4.3        1.7
low         6.7        0.75
==========  =========  ==========

* ``'default'``: onnxruntime's defaults (arena, memory patterns, every graph optimisation).
  Fastest. Its constant folding evaluates the arithmetic on the baked sampling grids while
  the session is built (about 1.1 GB of resident memory that stays), and the arena keeps the
  largest working set of any run.
* ``'lean'``: the same without constant folding; the grid arithmetic then runs in each
  forward (a few elementwise ops on the baked grids, cheap beside the convolutions).
* ``'low'``: the least resident memory. Constant folding is off, the CPU arena and memory
  patterns are off (each tensor is freed when its last reader is done), and glibc's mmap
  threshold is fixed at 1 MiB
  (:func:`gijax.host_memory.fix_mmap_threshold`), so every large buffer is mapped and
  returned to the system when freed instead of staying in the heap. Without that last
  setting glibc raises its threshold after the first large free, and the resident set grows
  from one run to the next. The threshold is a process-wide setting: it stays for the life of
  the process and applies to every allocation in it (glibc only; elsewhere it is skipped).
  It costs time: every large buffer is faulted in afresh.
"""

from __future__ import annotations

from pathlib import Path

from gijax.host_memory import fix_mmap_threshold

MEMORY_PROFILES = ("default", "lean", "low")


def available_providers() -> list[str]:
    import onnxruntime as ort

    return list(ort.get_available_providers())


def default_providers() -> list[str]:
    """CUDA first when this onnxruntime has it, then the CPU."""
    have = available_providers()
    return [p for p in ("CUDAExecutionProvider", "CPUExecutionProvider") if p in have]


def session_options(memory: str = "default", threads: int | None = None):
    """(``onnxruntime.SessionOptions``, names of graph optimisers to disable) for a profile."""
    import onnxruntime as ort

    if memory not in MEMORY_PROFILES:
        raise ValueError(f"memory profile must be one of {MEMORY_PROFILES}; found {memory!r}")
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.log_severity_level = 3  # errors only: shape-merge notes are not actionable
    if threads:
        opts.intra_op_num_threads = int(threads)
    disabled = [] if memory == "default" else ["ConstantFolding"]
    if memory == "low":
        opts.enable_cpu_mem_arena = False
        opts.enable_mem_pattern = False
    return opts, disabled


def make_session(path: str | Path, providers=None, threads: int | None = None,
                 memory: str = "default"):
    """An ``onnxruntime.InferenceSession`` for ``path`` with full graph optimisation and the
    ``memory`` profile (module docstring); ``providers`` default to :func:`default_providers`."""
    import onnxruntime as ort

    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: no such ONNX file")
    opts, disabled = session_options(memory, threads)
    providers = default_providers() if providers is None else list(providers)
    unknown = [p for p in providers if p not in available_providers()]
    if unknown:
        raise ValueError(f"onnxruntime providers {unknown} are not available here; available: "
                         f"{available_providers()}")
    if memory == "low":
        fix_mmap_threshold()
    return ort.InferenceSession(str(path), sess_options=opts, providers=providers,
                                disabled_optimizers=disabled or None)


__all__ = ["MEMORY_PROFILES", "available_providers", "default_providers", "make_session",
           "session_options"]
