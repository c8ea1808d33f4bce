"""TensorRT compatibility report of an ONNX graph: every operator and data type checked against
TensorRT 8.5 (JetPack 5), 10.x (JetPack 6.1 / 6.2) and 11.x, plus the IR version onnxruntime reads.

The checker is table driven; every rule below is one row of :data:`OP_RULES` or one of the
graph-level rules in :func:`check_model`. Data types are grouped as ``f32 f16 bf16 f64 i64 i32
i8 u8 bool``; an operator's *data type* is that of its first input (the second for ``Where``).

Graph-level rules (errors unless stated):

* opset of the default domain <= the target's maximum (8.5: 17; 10.x: 20; 11.x: 22);
* IR version <= what the target's ONNX parser reads (8.5: 8; 10.x: 10; 11.x: 11) and
  <= 13 (onnxruntime 1.31);
* no operator from a custom domain (no plugins are shipped) and no ONNX local functions;
* graph inputs / outputs are f32, f16, i32, i8, u8 or bool (not f64; not i64 on 8.5);
* int64 / float64 tensors inside the graph: a *warning* on 8.5 (the parser casts them down to
  int32 / float32, clamping values), fine on 10.x and later;
* symbolic (dynamic) dimensions: a *warning* (the engine needs an optimisation profile).
* float16 tensors (a ``--precision fp16`` export): a *warning* on 8.5 (no strongly typed mode:
  the ``--fp16`` builder flag lets TensorRT pick per layer, so the file's float32 islands are a
  request, not a guarantee) and on 10.x (build strongly typed to run the types as written:
  ``gijax trt build`` does so by default for such a file, ``trtexec`` needs
  ``--stronglyTyped``); 11.x networks are strongly typed.

Operator rules (:data:`OP_RULES`): the first TensorRT version that parses the operator and the
data types it accepts. Notable rows:

* ``Clip``: float only (f32, f16; i8 when quantised). Integer clamps must be written Max/Min.
* ``IsInf``: from 10.0 (8.5's parser rejects it); ``IsNaN`` from 8.5.
* ``GridSample``: from 8.6, 4-D input only before 11.2 (5-D from 11.2).
* ``Conv``: 2-D or 3-D (rank 4 or 5), weights must be an initializer or a constant.
* ``ConvTranspose``: 2-D only here. 3-D transposed convolutions are rejected by this checker
  (jax2onnx does not produce them, and TensorRT restricts their padding and output shape; the
  network uses upsample + conv instead).
* ``Range``: float start/limit/delta must be constants.
* ``QuantizeLinear`` (float input) and ``DequantizeLinear`` (int8 input; an int32 bias is
  rejected): explicit int8 quantisation, from 8.5. A ``Conv`` weight that is a
  ``DequantizeLinear`` of a constant counts as constant.
* ``Cast``: to f32, f16, i32, i64, i8, u8 or bool (i64 cast down on 8.5); bf16 from 9.0; f64
  and other targets are rejected.
* Reductions, Softmax, trigonometry, ``Floor``, ``Sqrt``, ``Pow``...: float only.
* Elementwise arithmetic, comparisons, ``Where``, gathers, shape ops: float, int32 (int64 cast
  down) and, where the op moves data only, int8 / bool.
* Any operator not in the table is an error (unknown to the checker = not known to build).
"""

from __future__ import annotations

import dataclasses
from collections import Counter, defaultdict
from typing import Callable, Optional

ORT_MAX_IR = 13  # onnxruntime 1.31


@dataclasses.dataclass(frozen=True)
class Target:
    key: str
    label: str
    version: tuple
    max_opset: int
    max_ir: int


TARGETS = (
    Target("trt8.5", "TensorRT 8.5 (JetPack 5)", (8, 5), 17, 8),
    Target("trt10", "TensorRT 10.x (JetPack 6.1+)", (10, 3), 20, 10),
    Target("trt11", "TensorRT 11.x", (11, 0), 22, 11),
)
TARGET_KEYS = tuple(t.key for t in TARGETS)

# ONNX TensorProto element types -> short class names.
_DTYPES = {1: "f32", 10: "f16", 16: "bf16", 11: "f64", 7: "i64", 6: "i32", 3: "i8", 2: "u8",
           9: "bool", 4: "u16", 5: "i16", 12: "u32", 13: "u64", 8: "string"}

F = frozenset({"f32", "f16"})
FI = F | {"i32"}
FIB = FI | {"bool"}
MOVE = FI | {"i8", "bool"}  # ops that only move or reshape data
BOOL = frozenset({"bool"})


@dataclasses.dataclass(frozen=True)
class OpRule:
    """``since``: first TensorRT version (major, minor) whose parser accepts the op;
    ``types``: accepted data types; ``check(node, ctx, target)``: extra rule -> message|None."""

    since: tuple
    types: frozenset
    check: Optional[Callable] = None
    data_input: int = 0


@dataclasses.dataclass
class Context:
    dtypes: dict          # tensor name -> short dtype
    ranks: dict           # tensor name -> rank (when known)
    constants: set        # initializer and Constant-node outputs


def _rank(ctx: Context, name: str):
    return ctx.ranks.get(name)


def _conv_check(node, ctx, target):
    r = _rank(ctx, node.input[0])
    if r is not None and r not in (4, 5):
        return f"{r - 2}-D convolution: TensorRT takes 2-D or 3-D only"
    if len(node.input) > 1 and node.input[1] not in ctx.constants:
        return "weights are a graph tensor: TensorRT needs them as an initializer / constant"
    return None


def _deconv_check(node, ctx, target):
    r = _rank(ctx, node.input[0])
    if r == 5:
        return ("3-D ConvTranspose: rejected (TensorRT restricts 3-D deconvolution padding and "
                "output shapes; use trilinear upsampling + Conv)")
    if r is not None and r != 4:
        return f"{r - 2}-D ConvTranspose: only 2-D is accepted"
    return None


def _grid_sample_check(node, ctx, target):
    r = _rank(ctx, node.input[0])
    if r is not None and r != 4 and target.version < (11, 2):
        return (f"{r}-D GridSample: TensorRT before 11.2 supports 4-D input only (use the "
                f"gather-based sampler)")
    return None


def _range_check(node, ctx, target):
    if ctx.dtypes.get(node.input[0]) in ("f32", "f16"):
        if any(i not in ctx.constants for i in node.input):
            return "float Range needs constant start, limit and delta"
    return None


def _clip_check(node, ctx, target):
    if ctx.dtypes.get(node.input[0]) in ("i32", "i64"):
        return "integer Clip: TensorRT's Clip takes float only (clamp integers with Max/Min)"
    return None


_CAST_TARGETS = frozenset({"f32", "f16", "i32", "i64", "i8", "u8", "bool"})


def _cast_check(node, ctx, target):
    to = next((a.i for a in node.attribute if a.name == "to"), None)
    name = _DTYPES.get(to, str(to))
    if name == "bf16" and target.version < (9, 0):
        return "Cast to bf16: TensorRT reads bf16 from 9.0"
    if name not in _CAST_TARGETS | {"bf16"}:
        return f"Cast to {name}: TensorRT casts to {', '.join(sorted(_CAST_TARGETS))} only"
    return None


def _einsum_check(node, ctx, target):
    eq = next((a.s.decode() for a in node.attribute if a.name == "equation"), "")
    if "..." in eq:
        return "Einsum with an ellipsis is not supported"
    return None


def _rows():
    rows = {}
    v85 = (8, 5)
    for op in ("Add", "Sub", "Mul", "Div", "Max", "Min", "Sum", "Mean", "Neg", "Abs",
               "Equal", "Greater", "GreaterOrEqual", "Less", "LessOrEqual", "Sign"):
        rows[op] = OpRule(v85, FI)
    for op in ("Pow", "Sqrt", "Exp", "Log", "Sin", "Cos", "Tan", "Asin", "Acos", "Atan",
               "Sinh", "Cosh", "Tanh", "Asinh", "Acosh", "Atanh", "Floor", "Ceil", "Erf",
               "Sigmoid", "Relu", "LeakyRelu", "Elu", "Selu", "Softplus", "Softsign", "PRelu",
               "HardSigmoid", "Softmax", "LogSoftmax", "BatchNormalization",
               "InstanceNormalization", "ReduceSum", "ReduceMean", "ReduceMax", "ReduceMin",
               "ReduceProd", "ReduceSumSquare", "ReduceL1", "ReduceL2", "ReduceLogSumExp",
               "MatMul", "Gemm", "Resize", "Upsample", "AveragePool", "MaxPool",
               "GlobalAveragePool", "GlobalMaxPool", "Round", "CumSum", "ArgMax", "ArgMin",
               "TopK"):
        rows[op] = OpRule(v85, F)
    for op in ("And", "Or", "Not", "Xor"):
        rows[op] = OpRule(v85, BOOL)
    for op in ("Concat", "Reshape", "Transpose", "Slice", "Squeeze", "Unsqueeze", "Expand",
               "Flatten", "Identity", "Shape", "Size", "Split", "Tile", "Gather",
               "GatherElements", "GatherND", "Constant", "ConstantOfShape", "Pad",
               "ScatterND", "ScatterElements", "DepthToSpace", "SpaceToDepth"):
        rows[op] = OpRule(v85, MOVE)
    rows["Cast"] = OpRule(v85, MOVE | {"u8"}, _cast_check)
    # Explicit (QDQ) int8 quantisation: float in, int8 out and back.
    rows["QuantizeLinear"] = OpRule(v85, F)
    rows["DequantizeLinear"] = OpRule(v85, frozenset({"i8"}))
    rows["Where"] = OpRule(v85, FIB, data_input=1)
    rows["IsNaN"] = OpRule(v85, FI)
    rows["IsInf"] = OpRule((10, 0), F)
    rows["Clip"] = OpRule(v85, F | {"i8", "i32"}, _clip_check)
    rows["Conv"] = OpRule(v85, F | {"i8"}, _conv_check)
    rows["ConvTranspose"] = OpRule(v85, F | {"i8"}, _deconv_check)
    rows["GridSample"] = OpRule((8, 6), F, _grid_sample_check)
    rows["Range"] = OpRule(v85, FI, _range_check)
    rows["Einsum"] = OpRule(v85, F, _einsum_check)
    rows["LayerNormalization"] = OpRule((8, 6), F)
    rows["Reciprocal"] = OpRule((8, 6), F)
    return rows


OP_RULES: dict = _rows()


@dataclasses.dataclass(frozen=True)
class Finding:
    target: str      # a Target key, or 'onnxruntime'
    severity: str    # 'error' | 'warning'
    op: str          # operator type, or '(graph)'
    message: str
    node: str = ""


@dataclasses.dataclass
class CompatReport:
    """Findings per target, plus the operator / data-type inventory of the graph."""

    findings: list
    op_counts: dict       # op type -> count
    op_dtypes: dict       # op type -> sorted data types seen
    opset: int
    ir_version: int

    def errors(self, target: str | None = None) -> list:
        return [f for f in self.findings if f.severity == "error"
                and (target is None or f.target == target)]

    def warnings(self, target: str | None = None) -> list:
        return [f for f in self.findings if f.severity == "warning"
                and (target is None or f.target == target)]

    def ok(self, target: str | None = None) -> bool:
        return not self.errors(target)

    def table(self) -> str:
        """Text table: one row per operator (count, data types, status per target), then the
        graph-level findings."""
        keys = list(TARGET_KEYS)
        head = f"{'operator':22s} {'count':>5s}  {'types':18s} " + " ".join(f"{k:>8s}" for k in keys)
        lines = [f"ONNX opset {self.opset}, IR version {self.ir_version}", head, "-" * len(head)]
        per_op = defaultdict(dict)
        for f in self.findings:
            if f.op != "(graph)" and f.target in keys:
                cur = per_op[f.op].get(f.target)
                if cur != "FAIL":
                    per_op[f.op][f.target] = "FAIL" if f.severity == "error" else "warn"
        for op in sorted(self.op_counts):
            status = " ".join(f"{per_op[op].get(k, 'ok'):>8s}" for k in keys)
            types = ",".join(self.op_dtypes.get(op, []))
            lines.append(f"{op:22s} {self.op_counts[op]:5d}  {types:18s} {status}")
        lines.append("")
        for t in TARGETS:
            errs, warns = self.errors(t.key), self.warnings(t.key)
            verdict = "OK" if not errs else f"FAILS ({len(errs)} error(s))"
            lines.append(f"{t.label}: {verdict}" + (f", {len(warns)} warning(s)" if warns
                                                     else ""))
        ort_errs = self.errors("onnxruntime")
        lines.append(f"onnxruntime 1.31: {'OK' if not ort_errs else 'FAILS'}")
        seen = set()
        for f in self.findings:
            key = (f.target, f.severity, f.op, f.message)
            if key in seen:
                continue
            seen.add(key)
            where = f" [{f.node}]" if f.node else ""
            lines.append(f"  {f.severity.upper():7s} {f.target:11s} {f.op}{where}: {f.message}")
        return "\n".join(lines)

    def raise_if_errors(self, targets=None) -> None:
        """ValueError listing every error for ``targets`` (default: all)."""
        errs = [f for f in self.errors() if targets is None or f.target in targets]
        if errs:
            text = "\n".join(f"  {f.target}: {f.op} {f.node}: {f.message}" for f in errs)
            raise ValueError(f"the ONNX graph would not build:\n{text}")


def _context(model) -> Context:
    import onnx

    inferred = onnx.shape_inference.infer_shapes(model, strict_mode=False)
    g = inferred.graph
    dtypes, ranks = {}, {}
    for v in list(g.value_info) + list(g.input) + list(g.output):
        tt = v.type.tensor_type
        dtypes[v.name] = _DTYPES.get(tt.elem_type, str(tt.elem_type))
        if tt.HasField("shape"):
            ranks[v.name] = len(tt.shape.dim)
    constants = set()
    for t in g.initializer:
        dtypes[t.name] = _DTYPES.get(t.data_type, str(t.data_type))
        ranks[t.name] = len(t.dims)
        constants.add(t.name)
    for node in g.node:
        if node.op_type == "Constant":
            constants.add(node.output[0])
            for a in node.attribute:
                if a.name == "value":
                    dtypes[node.output[0]] = _DTYPES.get(a.t.data_type, str(a.t.data_type))
                    ranks[node.output[0]] = len(a.t.dims)
        elif node.op_type == "DequantizeLinear" and node.input[0] in constants:
            constants.add(node.output[0])  # quantised weights: TensorRT folds them
    return Context(dtypes, ranks, constants)


def check_model(model, targets=TARGETS) -> CompatReport:
    """Check an ``onnx.ModelProto`` (or a path) against ``targets``; see the module docstring."""
    import onnx

    if not isinstance(model, onnx.ModelProto):
        model = onnx.load(str(model))
    ctx = _context(model)
    g = model.graph
    findings: list = []
    opset = max((o.version for o in model.opset_import if o.domain in ("", "ai.onnx")),
                default=0)
    ir = model.ir_version
    if ir > ORT_MAX_IR:
        findings.append(Finding("onnxruntime", "error", "(graph)",
                                f"IR version {ir} > {ORT_MAX_IR}: onnxruntime 1.31 cannot "
                                f"read it"))
    for t in targets:
        if opset > t.max_opset:
            findings.append(Finding(t.key, "error", "(graph)",
                                    f"opset {opset} > {t.max_opset}, the newest {t.label} "
                                    f"parses (export with --opset {t.max_opset})"))
        if ir > t.max_ir:
            findings.append(Finding(t.key, "error", "(graph)",
                                    f"IR version {ir} > {t.max_ir}, the newest {t.label}'s "
                                    f"ONNX parser reads"))
        if len(model.functions):
            findings.append(Finding(t.key, "error", "(graph)",
                                    f"{len(model.functions)} ONNX local function(s): inline "
                                    f"them before building"))
        for io, kind in [(v, "input") for v in g.input] + [(v, "output") for v in g.output]:
            dt = ctx.dtypes.get(io.name)
            if dt == "f64" or (dt == "i64" and t.version < (10, 0)) or \
                    dt not in ("f32", "f16", "i32", "i64", "i8", "u8", "bool"):
                findings.append(Finding(t.key, "error", "(graph)",
                                        f"graph {kind} {io.name!r} has type {dt}, which "
                                        f"{t.label} does not take at the network boundary"))
        dynamic = [v.name for v in list(g.input) + list(g.output)
                   if any(d.dim_param or not d.HasField("dim_value")
                          for d in v.type.tensor_type.shape.dim)]
        if dynamic:
            findings.append(Finding(t.key, "warning", "(graph)",
                                    f"dynamic dimensions in {', '.join(dynamic)}: build with an "
                                    f"optimisation profile (--minShapes/--optShapes/--maxShapes)"))
    if any(dt == "f16" for dt in ctx.dtypes.values()):
        for t in targets:
            if t.version < (10, 0):
                findings.append(Finding(t.key, "warning", "(graph)", (
                    "float16 tensors: no strongly typed mode before 10.0; build with --fp16 "
                    "(the builder picks per layer, the float32 islands are not enforced)")))
            elif t.version < (11, 0):
                findings.append(Finding(t.key, "warning", "(graph)", (
                    "float16 tensors: build strongly typed to run the file's types as written "
                    "('gijax trt build' does by default, trtexec needs --stronglyTyped; "
                    "--fp16 instead lets the builder pick per layer)")))
    wide = {name for name, dt in ctx.dtypes.items() if dt in ("i64", "f64")}
    op_counts, op_dtypes = Counter(), defaultdict(set)
    wide_ops = defaultdict(Counter)
    for node in g.node:
        op = node.op_type
        op_counts[op] += 1
        rule = OP_RULES.get(op)
        data_name = node.input[rule.data_input] if rule and len(node.input) > rule.data_input \
            else (node.input[0] if node.input else (node.output[0] if node.output else ""))
        if op == "Constant" and node.output:
            data_name = node.output[0]
        dt = ctx.dtypes.get(data_name, "?")
        op_dtypes[op].add(dt)
        for t in targets:
            if node.domain not in ("", "ai.onnx"):
                findings.append(Finding(t.key, "error", op, f"custom domain {node.domain!r} "
                                        f"needs a TensorRT plugin", node.name))
                continue
            if rule is None:
                findings.append(Finding(t.key, "error", op, "operator not in the TensorRT "
                                        "support table", node.name))
                continue
            if t.version < rule.since:
                since = ".".join(map(str, rule.since))
                findings.append(Finding(t.key, "error", op, f"needs TensorRT >= {since}",
                                        node.name))
                continue
            narrow = {"i64": "i32", "f64": "f32"}.get(dt, dt)
            if dt != "?" and narrow not in rule.types:
                findings.append(Finding(t.key, "error", op, f"data type {dt} not supported "
                                        f"(accepted: {', '.join(sorted(rule.types))})",
                                        node.name))
            if rule.check is not None:
                msg = rule.check(node, ctx, t)
                if msg:
                    findings.append(Finding(t.key, "error", op, msg, node.name))
            if any(n in wide for n in list(node.input) + list(node.output)):
                wide_ops[t.key][op] += 1
    for t in targets:
        if t.version < (10, 0) and wide_ops[t.key]:
            ops = ", ".join(f"{k} x{v}" for k, v in sorted(wide_ops[t.key].items()))
            findings.append(Finding(t.key, "warning", "(graph)",
                                    f"int64/float64 tensors at {ops}: cast down to "
                                    f"int32/float32 by the parser (values clamped)"))
    return CompatReport(findings, dict(op_counts), {k: sorted(v) for k, v in op_dtypes.items()},
                        opset, ir)
