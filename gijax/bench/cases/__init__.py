"""The benchmark cases. Each takes a :class:`Context` and returns a JSON-ready dict with
``rows`` (one dict per measured configuration) and case-level fields.

Times are seconds inside the code and milliseconds in the rows (``*_ms``); memory is MiB.
Every program is compiled once (``jax.jit(...).lower(...).compile()``), which also yields its
FLOPs and bytes (XLA cost analysis) and its memory (XLA memory analysis).

* :mod:`~gijax.bench.cases.context`: the context and the row of a compiled program;
* :mod:`~gijax.bench.cases.calibration`: the device's measured limits;
* :mod:`~gijax.bench.cases.programs`: the network's programs (forward, sweep, stages);
* :mod:`~gijax.bench.cases.network`: forward, sweep, stages and scaling cases;
* :mod:`~gijax.bench.cases.onnx_runtime`: JAX vs onnxruntime on the exported graph;
* :mod:`~gijax.bench.cases.candidate_solver`: the rig-aware candidate solver;
* :mod:`~gijax.bench.cases.baseline`: the classical RTSS baseline;
* :mod:`~gijax.bench.cases.training`: one training step, and its stages forward and backward;
* :mod:`~gijax.bench.cases.isolated`: every preset in fresh processes (:mod:`gijax.bench.isolated`);
* :mod:`~gijax.bench.cases.precision`: onnxruntime on the fp32, fp16 and int8 files, fresh
  processes;
* :mod:`~gijax.bench.cases.torch_peer`: gijax against its PyTorch twin (:mod:`gijax.bench.torch_peer`).
"""

from __future__ import annotations

from gijax.bench.cases.baseline import rtss
from gijax.bench.cases.calibration import calibrate
from gijax.bench.cases.candidate_solver import candidates
from gijax.bench.cases.context import Context
from gijax.bench.cases.isolated import isolated
from gijax.bench.cases.network import forward, scaling, stages, sweep
from gijax.bench.cases.onnx_runtime import onnx_vs_jax
from gijax.bench.cases.precision import precision
from gijax.bench.cases.torch_peer import torch_peer
from gijax.bench.cases.training import train_stages, train_step

CASES = {
    "forward": forward,
    "onnx": onnx_vs_jax,
    "sweep": sweep,
    "stages": stages,
    "candidates": candidates,
    "rtss": rtss,
    "train": train_step,
    "train-stages": train_stages,
    "scaling": scaling,
    "isolated": isolated,
    "precision": precision,
    "torch-peer": torch_peer,
}

__all__ = ["CASES", "Context", "calibrate"]
