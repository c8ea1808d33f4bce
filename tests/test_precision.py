"""Reduced-precision export: the fp16 plan's islands in the file, its accuracy against the fp32
file (and against a naive all-fp16 conversion), and the TensorRT report on fp16 graphs."""

import dataclasses
import json

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper

from gijax.candidates.spec import resolve_candidates
from gijax.cli import main
from gijax.export.onnx_export import OUTPUTS, export_onnx, read_metadata, rendered_inputs
from gijax.export.precision import naive_fp16
from gijax.export.trt_compat import check_model
from gijax.io.rigfile import load_rig
from gijax.model import create_model
from gijax.nn.presets import get_preset

# The smallest network with every stage (as in test_export.py).
TINY = dataclasses.replace(
    get_preset("G16V-released-cpu"), name="tiny-precision", feature_blocks=(1, 1),
    surrogate_hw=(32, 128), cost_hw=(8, 32), output_hw=(16, 64), num_candidates=8,
    unet_base=8, feature_channels=4, unet_in=4, image_scale=0.125)
FP16_ATOL = 1e-3  # 1/m: the plan's stated tolerance on this model (measured ~1e-6)


def _session(path):
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def _run(path, images, masks):
    return dict(zip(OUTPUTS, _session(path).run(list(OUTPUTS), {"images": images,
                                                               "masks": masks})))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("precision")
    cfg_file = d / "tiny.json"
    cfg_file.write_text(json.dumps({k: list(v) if isinstance(v, tuple) else v
                                    for k, v in dataclasses.asdict(TINY).items()}))
    code = main(["export", "--preset", str(cfg_file), "--rig", "paper-train", "--out",
                 str(d / "fp16.onnx"), "--precision", "fp16", "--no-validate"])
    assert code == 0  # written, checked and TensorRT-clean (fp32 vs JAX: test_export.py)
    rig = load_rig("paper-train")
    # What --candidates train gives an untrained preset.
    cand, _ = resolve_candidates("train", rig, TINY.num_candidates, TINY.d_min, TINY.d_max,
                                 kind=TINY.candidates)
    model = create_model(TINY, seed=0)
    export_onnx(model, rig, cand, d / "fp32.onnx")
    export_onnx(model, rig, cand, d / "int8.onnx", precision="int8", calibration_scenes=2)
    naive = onnx.load(str(d / "fp32.onnx"))
    naive_fp16(naive)
    onnx.save_model(naive, str(d / "naive.onnx"))
    images, masks = rendered_inputs(TINY, rig, seed=3)
    out = {k: _run(d / f"{k}.onnx", images, masks) for k in ("fp32", "fp16", "naive", "int8")}
    return dict(dir=d, out=out, cand=cand)


def _types(proto):
    g = onnx.shape_inference.infer_shapes(proto).graph
    t = {v.name: v.type.tensor_type.elem_type
         for v in list(g.value_info) + list(g.input) + list(g.output)}
    t.update({i.name: i.data_type for i in g.initializer})
    return t


def test_fp16_plan_keeps_accuracy_and_beats_naive_conversion(files):
    out = files["out"]
    ref = out["fp32"]
    d_plan = np.abs(out["fp16"]["inv_distance"] - ref["inv_distance"])
    d_naive = np.abs(out["naive"]["inv_distance"] - ref["inv_distance"])
    assert d_plan.max() <= FP16_ATOL, d_plan.max()
    np.testing.assert_allclose(out["fp16"]["entropy"], ref["entropy"], atol=1e-3, rtol=0)
    np.testing.assert_array_equal(out["fp16"]["valid"], ref["valid"])
    # The naive file rounds the candidates' inverse distances and the sweep coordinates: its
    # error is well above the plan's.
    assert d_naive.mean() > 10 * d_plan.mean(), (d_naive.mean(), d_plan.mean())
    # Soft-argmax inside the candidate range (an independent bound).
    assert np.all(out["fp16"]["inv_distance"] <= 1 / files["cand"][0] + 1e-4)


def test_fp16_file_has_the_plan_islands(files):
    fp16 = onnx.load(str(files["dir"] / "fp16.onnx"))
    onnx.checker.check_model(fp16, full_check=True)
    t = _types(fp16)
    g = fp16.graph
    assert all(t[v.name] == TensorProto.FLOAT for v in list(g.input) + list(g.output)
               if v.name != "valid")
    convs = [n for n in g.node if n.op_type == "Conv"]
    assert convs and all(t[n.input[0]] == TensorProto.FLOAT16 and
                         t[n.input[1]] == TensorProto.FLOAT16 for n in convs)
    gathers = [n for n in g.node if n.op_type == "GatherND"]
    assert gathers and all(t[n.input[0]] == TensorProto.FLOAT for n in gathers)
    softmax = [n for n in g.node if n.op_type in ("Softmax", "LogSoftmax")]
    assert len(softmax) == 1 and t[softmax[0].input[0]] == TensorProto.FLOAT
    to = [next(a.i for a in n.attribute if a.name == "to") for n in g.node
          if n.op_type == "Cast" and n.name.startswith("precision_")]
    assert TensorProto.FLOAT16 in to and TensorProto.FLOAT in to
    meta = read_metadata(fp16)
    islands = json.loads(meta["fp16_islands"])
    assert meta["precision"] == "fp16" and len(islands) == 2  # features; cost volume + U-Net
    assert sum(i["convs"] for i in islands) == len(convs)
    assert "precision" not in read_metadata(onnx.load(str(files["dir"] / "fp32.onnx")))


def test_tensorrt_report_covers_fp16_and_casts(files):
    report = check_model(files["dir"] / "fp16.onnx")
    assert report.ok(), report.table()
    assert "f16" in report.op_dtypes["Conv"] and "Cast" in report.op_counts
    notes = [f.target for f in report.warnings() if "float16" in f.message]
    assert notes == ["trt8.5", "trt10"]
    # A cast to float64 does not build on any target.
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [2])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [2])
    graph = helper.make_graph([helper.make_node("Cast", ["x"], ["w"], to=TensorProto.DOUBLE),
                               helper.make_node("Cast", ["w"], ["y"], to=TensorProto.FLOAT)],
                              "g", [x], [y])
    bad = check_model(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]))
    assert {f.target for f in bad.errors() if f.op == "Cast"} == {"trt8.5", "trt10", "trt11"}


def test_unknown_precision_is_refused_before_export():
    with pytest.raises(ValueError, match="precision must be one of fp32, fp16, int8; found 'int4'"):
        export_onnx(create_model(TINY, seed=0), load_rig("paper-train"),
                    np.geomspace(0.5, 100.0, 8), "unused.onnx", precision="int4")


def test_int8_quantises_only_the_island_convolutions(files):
    q = onnx.load(str(files["dir"] / "int8.onnx"))
    onnx.checker.check_model(q, full_check=True)
    g = q.graph
    producer = {o: n for n in g.node for o in n.output}
    inits = {t.name: t for t in g.initializer}
    convs = [n for n in g.node if n.op_type == "Conv"]
    assert convs and all(producer[n.input[0]].op_type == "DequantizeLinear" and
                         producer[n.input[1]].op_type == "DequantizeLinear" for n in convs)
    # Weights per output channel: one scale per channel along axis 0.
    w_dq = producer[convs[0].input[1]]
    assert inits[w_dq.input[1]].dims == [inits[w_dq.input[0]].dims[0]]
    assert inits[w_dq.input[0]].data_type == TensorProto.INT8
    # The float32 islands stay unquantised: the sampling gathers and the softmax read floats.
    for n in g.node:
        if n.op_type in ("GatherND", "LogSoftmax", "Softmax"):
            assert producer.get(n.input[0]) is None or \
                producer[n.input[0]].op_type != "DequantizeLinear", n.name
    meta = read_metadata(q)
    assert meta["precision"] == "int8" and len(json.loads(meta["int8_islands"])) == 2
    assert check_model(q).ok(), check_model(q).table()
    d = np.abs(files["out"]["int8"]["inv_distance"] - files["out"]["fp32"]["inv_distance"])
    assert d.max() <= 5e-2, d.max()  # the stated int8 validation tolerance, 1/m
    np.testing.assert_array_equal(files["out"]["int8"]["valid"], files["out"]["fp32"]["valid"])
