"""TensorRT engines from exported ONNX files: build (branching on the installed version), load
(with a clear error for engines of another TensorRT version) and run.

Version differences handled here:

* 8.x: networks from ONNX need the EXPLICIT_BATCH creation flag; the workspace is a memory-pool
  limit (8.4+); fp16 is the FP16 builder flag.
* 10.x: explicit batch is implicit (no flag); fp16 is still the FP16 builder flag. Strongly
  typed networks (the STRONGLY_TYPED creation flag, ``trtexec --stronglyTyped``) are an opt-in:
  every tensor keeps the type the ONNX file gives it, so a ``--precision fp16`` export runs its
  float16 islands in fp16 and its float32 islands in fp32, and an int8 (QDQ) export quantises
  where its Q/DQ pairs say. That is the default here for a file with float16 tensors or Q/DQ
  nodes; a plain float32 file keeps the weakly typed build (``fp16=True`` lets the builder
  pick fp16 per layer).
* 11.x: the FP16 builder flag is gone and networks are always strongly typed: precision comes
  from the ONNX file (convert it to mixed precision before building), so ``fp16=True`` is an
  error.

A strongly typed network takes no precision builder flag (TensorRT refuses FP16 / INT8 flags
and per-layer precisions on it), so ``strongly_typed=True`` with ``fp16=True`` is an error, and
so is ``strongly_typed`` on 8.x (no such mode) or ``strongly_typed=False`` on 11.x.

Next to every engine ``model.plan`` a ``model.plan.json`` records the TensorRT version and the
GPU that built it; :func:`load_engine` compares it with the running TensorRT before
deserialising, and reports a plan that the runtime refuses.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from gijax.io.paths import write_bytes_atomic, write_json_atomic


class TensorRTMissing(RuntimeError):
    """TensorRT's Python package is not installed."""


def import_tensorrt():
    """The ``tensorrt`` module, or :class:`TensorRTMissing` with a one-line explanation."""
    try:
        import tensorrt  # noqa: F401
    except ImportError:
        raise TensorRTMissing("TensorRT is not installed (no 'tensorrt' Python package): install "
                              "it on the target (JetPack / pip install tensorrt) or build with "
                              "trtexec there") from None
    return tensorrt


def trt_version(trt) -> tuple:
    """(major, minor) of a tensorrt module."""
    parts = str(trt.__version__).split(".")
    try:
        return int(parts[0]), int(parts[1]) if len(parts) > 1 else 0
    except ValueError:
        raise ValueError(f"unreadable TensorRT version {trt.__version__!r}") from None


def _onnx_inputs(onnx_path: str) -> list:
    """[(name, dims with -1 for symbolic)] of the ONNX file's graph inputs."""
    import onnx

    model = onnx.load(onnx_path, load_external_data=False)
    out = []
    for v in model.graph.input:
        dims = [d.dim_value if d.HasField("dim_value") else -1
                for d in v.type.tensor_type.shape.dim]
        out.append((v.name, dims))
    return out


def _shape_text(dims, batch: int) -> str:
    return "x".join(str(batch if d < 0 else d) for d in dims)


def typed_precision(onnx_path: str) -> str:
    """What the file's own types ask for: 'int8' when it has Q/DQ nodes, 'fp16' when it has
    float16 tensors (initializers, annotated values, constants or casts to float16), else
    'fp32'."""
    import onnx

    from gijax.export.precision import FLOAT16

    model = onnx.load(onnx_path, load_external_data=False)
    g = model.graph
    if any(n.op_type in ("QuantizeLinear", "DequantizeLinear") for n in g.node):
        return "int8"
    values = list(g.input) + list(g.output) + list(g.value_info)
    if any(t.data_type == FLOAT16 for t in g.initializer) or \
            any(v.type.tensor_type.elem_type == FLOAT16 for v in values):
        return "fp16"
    for n in g.node:
        for a in n.attribute:
            if (n.op_type == "Cast" and a.name == "to" and a.i == FLOAT16) or \
                    (a.name == "value" and a.t.data_type == FLOAT16):
                return "fp16"
    return "fp32"


def resolve_strongly_typed(version: tuple, fp16: bool, strongly_typed: bool | None,
                           file_precision: str, label: str = "") -> bool:
    """Whether the network is built strongly typed: ``strongly_typed`` as asked, or (None) the
    default: always on 11.x, on 10.x for a file whose types carry its precision (fp16, int8)
    unless the FP16 builder flag is asked for, never on 8.x. ValueError, in one line, for a
    contradictory request."""
    where = f"TensorRT {label or '.'.join(map(str, version))}"
    if strongly_typed and fp16:
        raise ValueError("--stronglyTyped and --fp16 contradict each other: a strongly typed "
                         "network takes its precision from the ONNX file's types and no "
                         "precision builder flag; drop --fp16 (a --precision fp16 export "
                         "builds as fp16)")
    if strongly_typed and version < (10, 0):
        raise ValueError(f"{where} has no strongly typed mode (TensorRT 10.0 and later); "
                         f"drop --stronglyTyped (--fp16 lets the builder pick fp16 per layer)")
    if strongly_typed is False and version >= (11, 0):
        raise ValueError(f"{where} builds every network strongly typed; drop "
                         f"--no-stronglyTyped")
    if strongly_typed is not None:
        return bool(strongly_typed)
    if version >= (11, 0):
        return True
    return version >= (10, 0) and not fp16 and file_precision in ("fp16", "int8")


def trtexec_command(onnx_path: str, plan_path: str, version: tuple, fp16: bool = False,
                    workspace_mb: int | None = None, max_batch: int = 1,
                    strongly_typed: bool | None = None) -> str:
    """The ``trtexec`` command line that builds the same engine on a device
    (``strongly_typed`` None: on 11.x only, as :func:`resolve_strongly_typed` for a float32
    file)."""
    if strongly_typed is None:
        strongly_typed = version >= (11, 0)
    cmd = ["trtexec", f"--onnx={onnx_path}", f"--saveEngine={plan_path}"]
    if workspace_mb:
        cmd.append(f"--memPoolSize=workspace:{int(workspace_mb)}" if version >= (8, 4)
                   else f"--workspace={int(workspace_mb)}")
    if fp16 and version < (11, 0):
        cmd.append("--fp16")
    if strongly_typed:
        cmd.append("--stronglyTyped")
    dynamic = [(n, d) for n, d in _onnx_inputs(onnx_path) if any(x < 0 for x in d)]
    if dynamic:
        for flag, b in (("--minShapes", 1), ("--optShapes", 1), ("--maxShapes", max_batch)):
            cmd.append(flag + "=" + ",".join(f"{n}:{_shape_text(d, b)}" for n, d in dynamic))
    return " ".join(cmd)


def build_engine(onnx_path: str, plan_path: str, fp16: bool = False,
                 workspace_mb: int | None = None, max_batch: int = 1, trt=None,
                 strongly_typed: bool | None = None) -> dict:
    """Build and write a serialized engine; returns {'plan', 'version', 'trtexec', 'seconds',
    'strongly_typed', 'file_precision'}.

    ``strongly_typed``: build a strongly typed network (precision from the file's types);
    None: :func:`resolve_strongly_typed`'s default for the file. ``trt``: the tensorrt module
    (default: imported; tests inject a stand-in).
    """
    if strongly_typed and fp16:  # contradictory on any version: say so before anything else
        resolve_strongly_typed((11, 0), fp16, strongly_typed, "fp32")
    trt = import_tensorrt() if trt is None else trt
    version = trt_version(trt)
    if not Path(onnx_path).is_file():
        raise FileNotFoundError(f"{onnx_path}: no such ONNX file")
    if fp16 and version >= (11, 0):
        raise ValueError(f"TensorRT {trt.__version__} has no FP16 builder flag: precision comes "
                         f"from the ONNX file; convert {onnx_path} to mixed precision (e.g. "
                         f"'polygraphy convert --fp16' on TensorRT <= 10, or an fp16 ONNX "
                         f"conversion) and build without --fp16")
    file_precision = typed_precision(str(onnx_path))
    strongly_typed = resolve_strongly_typed(version, fp16, strongly_typed, file_precision,
                                            str(trt.__version__))
    logger = trt.Logger(trt.Logger.WARNING)
    builder = trt.Builder(logger)
    flags = 0
    if version < (10, 0):
        flags |= 1 << int(trt.NetworkDefinitionCreationFlag.EXPLICIT_BATCH)
    if strongly_typed:
        flags |= 1 << int(trt.NetworkDefinitionCreationFlag.STRONGLY_TYPED)
    network = builder.create_network(flags)
    parser = trt.OnnxParser(network, logger)
    if not parser.parse_from_file(str(onnx_path)):
        errors = [str(parser.get_error(i)) for i in range(parser.num_errors)]
        raise ValueError(f"{onnx_path}: TensorRT {trt.__version__} could not parse the ONNX "
                         f"file: " + "; ".join(errors))
    config = builder.create_builder_config()
    if workspace_mb:
        if version >= (8, 4):
            config.set_memory_pool_limit(trt.MemoryPoolType.WORKSPACE, int(workspace_mb) << 20)
        else:
            config.max_workspace_size = int(workspace_mb) << 20
    if fp16:
        config.set_flag(trt.BuilderFlag.FP16)
    dynamic = [(n, d) for n, d in _onnx_inputs(onnx_path) if any(x < 0 for x in d)]
    if dynamic:
        profile = builder.create_optimization_profile()
        for name, dims in dynamic:
            lo = tuple(1 if x < 0 else x for x in dims)
            hi = tuple(max_batch if x < 0 else x for x in dims)
            profile.set_shape(name, lo, lo, hi)
        config.add_optimization_profile(profile)
    start = time.perf_counter()
    plan = builder.build_serialized_network(network, config)
    if plan is None:
        raise ValueError(f"{onnx_path}: TensorRT {trt.__version__} failed to build an engine "
                         f"(see the log above)")
    seconds = time.perf_counter() - start
    write_bytes_atomic(plan_path, bytes(plan))
    info = {"tensorrt": str(trt.__version__), "gpu": _gpu_name(), "onnx": str(onnx_path),
            "fp16": bool(fp16), "strongly_typed": strongly_typed,
            "file_precision": file_precision}
    write_json_atomic(str(plan_path) + ".json", info)
    return {"plan": str(plan_path), "version": str(trt.__version__), "seconds": seconds,
            "strongly_typed": strongly_typed, "file_precision": file_precision,
            "trtexec": trtexec_command(str(onnx_path), str(plan_path), version, fp16,
                                       workspace_mb, max_batch, strongly_typed)}


def _gpu_name() -> str:
    try:
        import subprocess

        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=10)
        return out.stdout.strip().splitlines()[0] if out.returncode == 0 else ""
    except (OSError, IndexError, subprocess.SubprocessError):
        return ""


def load_engine(plan_path: str, trt=None):
    """Deserialise an engine; ValueError when it was built by another TensorRT version (from
    the build record next to it, or from the runtime refusing the plan)."""
    trt = import_tensorrt() if trt is None else trt
    path = Path(plan_path)
    if not path.is_file():
        raise FileNotFoundError(f"{plan_path}: no such engine file")
    record = Path(str(plan_path) + ".json")
    if record.is_file():
        built = json.loads(record.read_text()).get("tensorrt", "")
        if built and built.split(".")[:2] != str(trt.__version__).split(".")[:2]:
            raise ValueError(f"{plan_path} was built with TensorRT {built}; this is TensorRT "
                             f"{trt.__version__}. Engines are tied to the TensorRT version "
                             f"(and GPU): rebuild it here with 'gijax trt build'")
    runtime = trt.Runtime(trt.Logger(trt.Logger.WARNING))
    engine = runtime.deserialize_cuda_engine(path.read_bytes())
    if engine is None:
        raise ValueError(f"{plan_path}: TensorRT {trt.__version__} cannot deserialise this "
                         f"engine (built by another TensorRT version or for another GPU, or "
                         f"not an engine file); rebuild it here with 'gijax trt build'")
    return engine


def _cudart():
    try:
        from cuda.bindings import runtime as cudart
    except ImportError:
        try:
            from cuda import cudart
        except ImportError:
            raise TensorRTMissing("running an engine needs the 'cuda-python' package "
                                  "(pip install cuda-python)") from None
    return cudart


def _check(result):
    err = result[0] if isinstance(result, tuple) else result
    if int(err) != 0:
        raise RuntimeError(f"CUDA runtime error {err}")
    return result[1] if isinstance(result, tuple) and len(result) > 1 else None


def run_engine(engine, feed: dict, repeats: int = 10, trt=None) -> tuple[dict, list]:
    """Run ``engine`` on ``feed`` (name -> numpy array) ``repeats`` times; returns the outputs
    of the last run and the per-run wall times (seconds, including copies)."""
    trt = import_tensorrt() if trt is None else trt
    cudart = _cudart()
    version = trt_version(trt)
    context = engine.create_execution_context()
    names = [engine.get_tensor_name(i) for i in range(engine.num_io_tensors)]
    host, device = {}, {}
    for name in names:
        is_input = engine.get_tensor_mode(name) == trt.TensorIOMode.INPUT
        if is_input:
            if name not in feed:
                raise ValueError(f"the engine needs input {name!r}; given {sorted(feed)}")
            arr = np.ascontiguousarray(feed[name])
            context.set_input_shape(name, arr.shape)
            host[name] = arr
    for name in names:
        if name not in host:
            shape = tuple(context.get_tensor_shape(name))
            dtype = trt.nptype(engine.get_tensor_dtype(name))
            host[name] = np.empty(shape, dtype)
        device[name] = _check(cudart.cudaMalloc(host[name].nbytes))
        context.set_tensor_address(name, int(device[name]))
    stream = _check(cudart.cudaStreamCreate())
    h2d = cudart.cudaMemcpyKind.cudaMemcpyHostToDevice
    d2h = cudart.cudaMemcpyKind.cudaMemcpyDeviceToHost
    times = []
    try:
        for _ in range(repeats):
            t0 = time.perf_counter()
            for name in feed:
                _check(cudart.cudaMemcpy(device[name], host[name].ctypes.data,
                                         host[name].nbytes, h2d))
            ok = context.execute_async_v3(int(stream)) if version >= (8, 5) else \
                context.execute_v2([int(device[n]) for n in names])
            if not ok:
                raise RuntimeError("TensorRT execution failed")
            _check(cudart.cudaStreamSynchronize(stream))
            for name in names:
                if name not in feed:
                    _check(cudart.cudaMemcpy(host[name].ctypes.data, device[name],
                                             host[name].nbytes, d2h))
            times.append(time.perf_counter() - t0)
    finally:
        for ptr in device.values():
            cudart.cudaFree(ptr)
        cudart.cudaStreamDestroy(stream)
    return {n: host[n] for n in names if n not in feed}, times
