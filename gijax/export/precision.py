"""The precision plan of an exported graph: which nodes may run in float16, which stay float32.

A post-pass on the ONNX file jax2onnx wrote (after :func:`gijax.export.onnx_export.legalise`).
The graph's interface stays float32 (the predictors feed it unchanged); inside, the *fp16
islands* get float16 tensors, float16 initializers and constants, and a ``Cast`` on every edge
that crosses an island boundary. The types in the file then say exactly what runs in which
precision, which is what TensorRT's strongly typed mode builds as is.

The plan, by node position (the exported graph is a flat, topologically ordered node list):

* *Anchors* are the sampling gathers (``GatherND``, ``GatherElements``, ``Gather`` on float data,
  ``GridSample``) and the softmax (``Softmax`` / ``LogSoftmax``).
* An fp16 island is a run of convolutions with no anchor between them: it spans from the first
  ``Conv`` of the run to its last ``Conv``, and every float node in that span. In the network
  this gives the feature extractor (between the surrogate resampling and the sphere-sweep
  gathers) and the cost-volume convolution plus the 3-D U-Net (between the sweep gathers and
  the softmax). A spherical feature convolution gathers its taps, so it splits the feature
  island and its sampling stays float32.
* Everything else stays float32, for these reasons:

  - pixel coordinates and sweep grids: a 1024-pixel coordinate in float16 is resolved to
    0.5 px, and the bilinear weights are the fractional part of those coordinates;
  - bilinear weights and the weighted sums of the surrogate resampling and the sweep: they
    come straight from the coordinates above;
  - the masked-variance fusion (valid-camera counts and the division by them): it sits between
    the sweep gathers and the first cost-volume convolution, cheap, and its counts decide
    validity;
  - the logit upsampling, the softmax over the candidates and the inverse-distance regression:
    the expected value of 1/d over 8-16 close probabilities, and the entropy, lose digits in
    float16 (a probability near 1 keeps only 11 bits);
  - the validity output.

:func:`naive_fp16` converts every float node (one island spanning the whole graph, interface
kept float32) and is kept for comparison only.

:func:`quantize_int8` applies the same plan to int8: explicit quantisation (``QuantizeLinear`` /
``DequantizeLinear`` pairs, per-channel int8 weights, int8 activations calibrated on rendered
scenes) of the convolutions inside the islands; every node outside them stays float32 and
unquantised.
"""

from __future__ import annotations

import dataclasses

FLOAT, FLOAT16 = 1, 10  # onnx.TensorProto element types
SAMPLING_OPS = frozenset({"GatherND", "GatherElements", "Gather", "GridSample"})
SOFTMAX_OPS = frozenset({"Softmax", "LogSoftmax"})
PRECISIONS = ("fp32", "fp16", "int8")
DEFAULT_CALIBRATION_SCENES = 8
# Largest inverse-distance difference (1/m) from JAX an export may show, per precision: about 6x
# (fp16) and 3x (int8) the largest the bundled G16VV-cpu gives on rendered scenes (1.6e-3 and
# 6.5e-2 1/m, docs/deploy.md).
VALIDATE_ATOL = {"fp32": 1e-4, "fp16": 1e-2, "int8": 2e-1}
# Inputs whose type the operator fixes to float32 whatever the data type (ONNX spec).
_FLOAT32_ONLY_INPUTS = {"Resize": (2,), "Upsample": (1,)}
_SUFFIX16, _SUFFIX32 = "__fp16", "__fp32"


@dataclasses.dataclass(frozen=True)
class Island:
    """Node index range ``[first, last]`` (inclusive) of the graph that runs in float16."""

    first: int
    last: int
    convs: int  # convolutions in the range


def _float_data_gather(node, types) -> bool:
    return node.op_type in SAMPLING_OPS and types.get(node.input[0]) == FLOAT


def fp16_islands(proto) -> list:
    """The plan's fp16 islands of ``proto``'s main graph (see the module docstring)."""
    from gijax.export.onnx_export import _dtype_map

    types = _dtype_map(proto)
    islands, first, last, convs = [], None, None, 0
    for i, node in enumerate(proto.graph.node):
        if node.op_type in SOFTMAX_OPS or _float_data_gather(node, types):
            if first is not None:
                islands.append(Island(first, last, convs))
            first, last, convs = None, None, 0
        elif node.op_type == "Conv":
            first = i if first is None else first
            last, convs = i, convs + 1
    if first is not None:
        islands.append(Island(first, last, convs))
    return islands


def apply_fp16(proto, islands) -> dict:
    """Rewrite ``proto`` in place: the float nodes in ``islands`` run in float16, the rest
    stays float32, with casts at the boundaries. Returns counts: {'fp16_nodes', 'casts'}."""
    import numpy as np
    from onnx import helper, numpy_helper

    from gijax.export.onnx_export import _dtype_map

    g = proto.graph
    types = _dtype_map(proto)
    inside = set()
    for isl in islands:
        inside.update(range(isl.first, isl.last + 1))
    inits = {t.name: t for t in g.initializer}
    users = {}
    for i, node in enumerate(g.node):
        for name in node.input:
            users.setdefault(name, set()).add(i)
    half = set()          # tensors that now hold float16 under their own name
    cast16, cast32 = {}, {}
    new_inits = []
    new_nodes, fp16_nodes = [], 0

    def cast(name, to, cache, suffix):
        if name not in cache:
            out = name + suffix
            new_nodes.append(helper.make_node("Cast", [name], [out], to=to,
                                              name=f"precision_cast{len(cache)}{suffix}_{name}"))
            cache[name] = out
        return cache[name]

    def half_tensor(t):
        return numpy_helper.from_array(numpy_helper.to_array(t).astype(np.float16), t.name)

    for i, node in enumerate(g.node):
        if i not in inside:
            for k, name in enumerate(node.input):
                if name in half:
                    node.input[k] = cast(name, FLOAT, cast32, _SUFFIX32)
            new_nodes.append(node)
            continue
        fixed = _FLOAT32_ONLY_INPUTS.get(node.op_type, ())
        converted = False
        for k, name in enumerate(node.input):
            if not name or k in fixed or name in half or types.get(name) != FLOAT:
                continue
            if name in inits and users[name] <= inside:
                new_inits.append(name)
                half.add(name)
            elif name in inits:
                # Shared with float32 nodes: the island gets its own float16 copy.
                if name + _SUFFIX16 not in inits:
                    copy = half_tensor(inits[name])
                    copy.name = name + _SUFFIX16
                    g.initializer.append(copy)
                    inits[copy.name] = copy
                node.input[k] = name + _SUFFIX16
            else:
                node.input[k] = cast(name, FLOAT16, cast16, _SUFFIX16)
            converted = True
        for a in node.attribute:
            if node.op_type in ("Constant", "ConstantOfShape") and a.name == "value" \
                    and a.t.data_type == FLOAT:
                a.t.CopyFrom(half_tensor(a.t))
                converted = True
            elif node.op_type == "Cast" and a.name == "to" and a.i == FLOAT:
                a.i = FLOAT16
                converted = True
        for name in node.output:
            if types.get(name) == FLOAT:
                half.add(name)
                converted = True
        fp16_nodes += converted
        new_nodes.append(node)
    for name in new_inits:
        inits[name].CopyFrom(half_tensor(inits[name]))
    outputs = {o.name for o in g.output}
    for name in sorted(outputs & half):
        # A graph output computed in float16: the island writes a renamed tensor, a final cast
        # restores the float32 interface.
        renamed = name + _SUFFIX16
        for node in new_nodes:
            node.input[:] = [renamed if n == name else n for n in node.input]
            node.output[:] = [renamed if n == name else n for n in node.output]
        new_nodes.append(helper.make_node("Cast", [renamed], [name], to=FLOAT,
                                          name=f"precision_output_cast_{name}"))
    del g.node[:]
    g.node.extend(new_nodes)
    del g.value_info[:]
    return {"fp16_nodes": int(fp16_nodes), "casts": len(cast16) + len(cast32)
            + len(outputs & half)}


def plan_fp16(proto) -> dict:
    """Apply the precision plan to ``proto`` in place; returns the islands (node ranges of the
    original graph) and the counts of :func:`apply_fp16`."""
    islands = fp16_islands(proto)
    if not islands:
        raise ValueError("the graph has no convolution outside the sampling and softmax: "
                         "nothing for the fp16 plan to convert")
    counts = apply_fp16(proto, islands)
    return dict(counts, islands=[dataclasses.asdict(isl) for isl in islands])


def naive_fp16(proto) -> dict:
    """Every float node in float16 (interface float32): the comparison for the plan."""
    counts = apply_fp16(proto, [Island(0, len(proto.graph.node) - 1, 0)])
    return dict(counts, islands=[])


def quantize_int8(fp32_path, out_path, calibration_feeds) -> dict:
    """Quantise the fp32 file ``fp32_path`` into ``out_path`` (QDQ, per-channel int8 weights,
    int8 activations) with ``onnxruntime.quantization.quantize_static``. Only the ``Conv``
    nodes of the plan's islands are quantised; the rest is excluded. ``calibration_feeds``:
    a list of input dicts (name -> float32 array) the activation ranges are calibrated on.
    Returns {'quantized_convs', 'islands', 'calibration_feeds'}."""
    import onnx
    from onnxruntime.quantization import (CalibrationDataReader, QuantFormat, QuantType,
                                          quantize_static)

    if not calibration_feeds:
        raise ValueError("int8 quantisation needs at least one calibration input")
    proto = onnx.load(str(fp32_path))
    islands = fp16_islands(proto)
    inside = {i for isl in islands for i in range(isl.first, isl.last + 1)}
    nodes = proto.graph.node
    exclude = [n.name for i, n in enumerate(nodes) if i not in inside and n.name]

    class Feeds(CalibrationDataReader):
        def __init__(self):
            self._it = iter(calibration_feeds)

        def get_next(self):
            return next(self._it, None)

    import logging
    quiet = logging.getLogger()
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # the quantiser's pre-processing advice is not actionable
    try:
        quantize_static(str(fp32_path), str(out_path), Feeds(), quant_format=QuantFormat.QDQ,
                        per_channel=True, activation_type=QuantType.QInt8,
                        weight_type=QuantType.QInt8, op_types_to_quantize=["Conv"],
                        nodes_to_exclude=exclude,
                        # TensorRT dequantises int8 only: biases stay float32.
                        extra_options={"QuantizeBias": False})
    finally:
        quiet.setLevel(level)
    return {"quantized_convs": sum(n.op_type == "Conv" for i, n in enumerate(nodes)
                                   if i in inside),
            "islands": [dataclasses.asdict(isl) for isl in islands],
            "calibration_feeds": len(calibration_feeds)}
