"""``gijax bench``: the benchmark suite (speed, memory and efficiency) in one command."""

from __future__ import annotations


def _run(args) -> int:
    from gijax.bench.suite import run_from_args

    return run_from_args(args)


def register(sub) -> None:
    from gijax.bench.suite import add_arguments

    p = sub.add_parser(
        "bench",
        help="benchmark suite: latency, memory and efficiency of every stage, JSON + Markdown",
        description=(
            "Measures the machine's matmul FLOP/s and memory bandwidth, then the forward pass "
            "per preset (JAX, and onnxruntime on the exported file), the sphere sweep alone, "
            "the rig-aware candidate solver and its gradient, the classical RTSS baseline, a "
            "training step, and the scaling with cameras (3, 4, 5) and candidates (8, 16, 32). "
            "Every figure has warm-up, repeated runs, median and inter-quartile range, peak "
            "memory (XLA's accounting; device memory on a GPU, resident set on the CPU) and "
            "its FLOPs and bytes from XLA's cost analysis against the measured limits. Writes "
            "bench.json, bench.md and scaling.png to --out."),
    )
    add_arguments(p)
    p.set_defaults(func=_run)
