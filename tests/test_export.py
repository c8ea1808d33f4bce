"""ONNX export: parity with JAX, rig-as-input vs baked, TensorRT compatibility rules, legalisation,
checkpoint checks, and the TensorRT build/run logic against a stand-in ``tensorrt`` module."""

import dataclasses
import json
import types
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper

from gijax.cli import main
from gijax.export.onnx_export import (OUTPUTS, export_onnx, jax_reference, legalise,
                                      rendered_inputs)
from gijax.export.ort_predict import OnnxPredictor
from gijax.export.trt_compat import check_model
from gijax.io.rigfile import load_rig
from gijax.model import create_model, with_estimate
from gijax.nn.presets import get_preset

# The smallest network with every stage (variance cost volume, any camera count).
TINY = dataclasses.replace(
    get_preset("G16V-released-cpu"), name="tiny-export", feature_blocks=(1, 1),
    surrogate_hw=(32, 128), cost_hw=(8, 32), output_hw=(16, 64), num_candidates=8,
    unet_base=8, feature_channels=4, unet_in=4, image_scale=0.125)
CAND = np.geomspace(0.5, 100.0, 8)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("export")
    rig = load_rig("paper-train")
    model = create_model(TINY, seed=1)
    images, masks = rendered_inputs(TINY, rig, seed=3)
    ref = jax_reference(model, rig, images, masks, CAND)
    baked = export_onnx(model, rig, CAND, d / "baked.onnx")
    live = export_onnx(model, rig, CAND, d / "live.onnx", rig_as_input=True, dynamic_batch=True)
    return dict(dir=d, rig=rig, model=model, images=images, masks=masks, ref=ref, baked=baked,
                live=live)


def _session(path):
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def test_onnx_predictor_gives_the_shared_prediction_type(setup):
    from gijax.evaluate.prediction import Prediction, Predictor

    s = setup
    pred = OnnxPredictor(s["baked"].path, providers=["CPUExecutionProvider"])
    out = pred.predict(s["rig"], s["images"][0], s["masks"][0])
    assert isinstance(pred, Predictor) and isinstance(out, Prediction)
    # What an exported model gives: no candidate distribution and no colours.
    assert set(out) == {"inv_distance", "distance", "entropy", "valid", "candidates",
                        "panorama"}
    assert out.prob is None and out.valid.dtype == bool
    np.testing.assert_array_equal(out["inv_distance"], out.inv_distance)


def test_baked_export_matches_jax(setup):
    s = setup
    assert s["baked"].metadata["mode"] == "baked"
    assert [i.name for i in _session(s["baked"].path).get_inputs()] == ["images", "masks"]
    out = OnnxPredictor(s["baked"].path, providers=["CPUExecutionProvider"]).predict(
        s["rig"], s["images"][0], s["masks"][0])
    ref = s["ref"]
    assert out["inv_distance"].shape == TINY.output_hw
    np.testing.assert_allclose(out["inv_distance"], ref["inv_distance"][0], atol=1e-4, rtol=0)
    np.testing.assert_allclose(out["entropy"], ref["entropy"][0], atol=1e-4, rtol=0)
    np.testing.assert_array_equal(out["valid"], ref["valid"][0] > 0.5)
    # Soft-argmax stays inside the candidate range: an independent sanity bound.
    assert np.all(out["inv_distance"] <= 1 / CAND[0] + 1e-5)
    assert np.all(out["inv_distance"] >= 1 / CAND[-1] - 1e-6)
    assert 0.0 < out["valid"].mean() <= 1.0
    model = onnx.load(s["baked"].path)
    assert model.ir_version <= 8 and model.opset_import[0].version == 17
    onnx.checker.check_model(model, full_check=True)


def test_rig_as_input_dynamic_batch_matches_jax(setup):
    s = setup
    sess = _session(s["live"].path)
    names = [i.name for i in sess.get_inputs()]
    assert names == ["images", "masks", "intrinsics", "rotations", "translations", "reference",
                     "candidates"]
    assert sess.get_inputs()[0].shape[0] == "B"
    from gijax.export.onnx_export import rig_at_model_size
    from gijax.export.ort_predict import rig_feed

    feed = {"images": np.repeat(s["images"], 2, 0), "masks": np.repeat(s["masks"], 2, 0)}
    feed.update(rig_feed(rig_at_model_size(TINY, s["rig"]), CAND))
    got = dict(zip(OUTPUTS, sess.run(list(OUTPUTS), feed)))
    for b in range(2):
        np.testing.assert_allclose(got["inv_distance"][b], s["ref"]["inv_distance"][0],
                                   atol=1e-4, rtol=0)
        np.testing.assert_array_equal(got["valid"][b], s["ref"]["valid"][0])


def test_default_exports_are_tensorrt_clean(setup):
    for key in ("baked", "live"):
        report = check_model(setup[key].path)
        assert report.ok(), report.table()
        assert "Clip" not in {op for op, t in report.op_dtypes.items() if "i32" in t
                              or "i64" in t}
        assert report.op_counts.get("GridSample", 0) == 0
        assert report.op_counts.get("IsInf", 0) == 0  # legalised to Equal(Abs(x), inf)
        assert report.op_counts["Conv"] > 0 and report.op_counts["GatherND"] > 0


def test_rig_as_input_second_rig_equals_fresh_baked_export(setup):
    """A moved, re-calibrated rig fed to the rig-as-input file gives what a fresh export with
    that rig baked in gives."""
    s = setup
    rig2 = load_rig("paper-test2")            # 1 m baseline, reference at the centroid
    cams = tuple(dataclasses.replace(c, fx=c.fx * 1.03, cx=c.cx + 2.0) for c in rig2.cameras)
    rig2 = rig2.replace(cameras=cams)
    cand2 = np.geomspace(0.7, 80.0, 8)
    fresh = export_onnx(s["model"], rig2, cand2, s["dir"] / "fresh.onnx")
    rng = np.random.default_rng(0)
    h, w = fresh.inputs["images"][2:4]
    images = rng.integers(0, 256, (3, h, w, 3), dtype=np.uint8)
    a = OnnxPredictor(s["live"].path, providers=["CPUExecutionProvider"]).predict(
        rig2, images, candidates=cand2)
    b = OnnxPredictor(fresh.path, providers=["CPUExecutionProvider"]).predict(rig2, images)
    np.testing.assert_allclose(a["inv_distance"], b["inv_distance"], atol=1e-4, rtol=0)
    np.testing.assert_array_equal(a["valid"], b["valid"])
    # ...and differs from the training rig's answer (the rig input is really used).
    c = OnnxPredictor(s["baked"].path, providers=["CPUExecutionProvider"]).predict(
        s["rig"], images)
    assert np.abs(a["inv_distance"] - c["inv_distance"]).max() > 1e-3
    with pytest.raises(ValueError, match="baked in"):
        OnnxPredictor(fresh.path).predict(rig2, images, candidates=CAND)


def test_matching_cost_model_exports_and_matches_jax(tmp_path):
    """The bundled design's parts: the matching-cost channel (grey sampling, cell ZNCC) and its
    skip to the logits, the cost volume at the output's resolution and the sub-pixel mode read
    at a pick of one candidate export at opset 17 with sums only (ReduceMean / ReduceMin would
    need axes attributes; the mode's pick and window are shifted sums, a maximum and
    comparisons, no ArgMax), match JAX and stay TensorRT-clean."""
    cfg = dataclasses.replace(TINY, name="tiny-zncc", matching_cost="zncc", matching_samples=2,
                              output_stride=1, output_hw=TINY.cost_hw, estimate="mode",
                              matching_skip=True, mode_pick=1)
    rig = load_rig("paper-train")
    model = create_model(cfg, seed=1)
    images, masks = rendered_inputs(cfg, rig, seed=3)
    without_skip = jax_reference(model, rig, images, masks, CAND)
    # The skip as trained, not at its zero start, so that the export must carry it.
    model.matching_skip.conv.kernel[...] = jnp.asarray(
        np.random.default_rng(2).normal(0.0, 0.3, (3, 3, 3, 1, 1)), jnp.float32)
    ref = jax_reference(model, rig, images, masks, CAND)
    assert np.abs(ref["inv_distance"] - without_skip["inv_distance"]).max() > 1e-2
    exported = export_onnx(model, rig, CAND, tmp_path / "zncc.onnx")
    out = OnnxPredictor(exported.path, providers=["CPUExecutionProvider"]).predict(
        rig, images[0], masks[0])
    np.testing.assert_allclose(out["inv_distance"], ref["inv_distance"][0], atol=1e-4, rtol=0)
    report = check_model(exported.path)
    assert report.ok(), report.table()
    assert report.op_counts.get("ReduceMean", 0) == 0
    assert report.op_counts.get("ArgMax", 0) == 0
    # The same weights read by the mean differ: what was exported is the mode.
    mean = jax_reference(with_estimate(model, "mean"), rig, images, masks, CAND)
    assert np.abs(out["inv_distance"] - mean["inv_distance"][0]).max() > 1e-2


def test_concat_model_refuses_other_camera_count():
    cfg = dataclasses.replace(TINY, name="tiny-concat", cost_volume="concat", unet_in=12)
    model = create_model(cfg)
    with pytest.raises(ValueError, match="exactly 3 cameras.*has 4"):
        export_onnx(model, load_rig("paper-test3"), CAND, "/nonexistent/never.onnx")


# ----------------------------------------------------------------------------- compat rules

def _model(nodes, inputs, outputs, opset=17, ir=8, inits=()):
    g = helper.make_graph(nodes, "g", inputs, outputs, initializer=list(inits))
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", opset)])
    m.ir_version = ir
    return m


def _vi(name, dtype, shape):
    return helper.make_tensor_value_info(name, dtype, shape)


def _errors(report, target):
    return " | ".join(f.message for f in report.errors(target))


def test_compat_flags_integer_clip():
    m = _model([helper.make_node("Clip", ["x", "lo", "hi"], ["y"])],
               [_vi("x", TensorProto.INT32, [4])], [_vi("y", TensorProto.INT32, [4])],
               inits=[helper.make_tensor("lo", TensorProto.INT32, [], [0]),
                      helper.make_tensor("hi", TensorProto.INT32, [], [2])])
    r = check_model(m)
    for t in ("trt8.5", "trt10", "trt11"):
        assert "integer Clip" in _errors(r, t)
    # The same clamp after legalisation: no Clip left, same numbers as numpy, report clean.
    legalise(m)
    assert "Clip" not in {n.op_type for n in m.graph.node}
    x = np.array([-3, 0, 1, 7], np.int32)
    y = _session_from(m).run(None, {"x": x})[0]
    np.testing.assert_array_equal(y, np.clip(x, 0, 2))
    assert check_model(m).ok()


def _session_from(m):
    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    return ort.InferenceSession(m.SerializeToString(), opts, providers=["CPUExecutionProvider"])


def test_isinf_legalised_and_rejected_before_trt10():
    m = _model([helper.make_node("IsInf", ["x"], ["y"])], [_vi("x", TensorProto.FLOAT, [5])],
               [_vi("y", TensorProto.BOOL, [5])])
    r = check_model(m)
    assert "needs TensorRT >= 10.0" in _errors(r, "trt8.5") and r.ok("trt10")
    legalise(m)
    x = np.array([np.inf, -np.inf, 0.0, 1e38, np.nan], np.float32)
    np.testing.assert_array_equal(_session_from(m).run(None, {"x": x})[0], np.isinf(x))
    assert check_model(m).ok("trt8.5")


def test_compat_flags_5d_grid_sample_before_11_2():
    m = _model([helper.make_node("GridSample", ["x", "g"], ["y"])],
               [_vi("x", TensorProto.FLOAT, [1, 2, 4, 4, 4]),
                _vi("g", TensorProto.FLOAT, [1, 3, 3, 3, 3])],
               [_vi("y", TensorProto.FLOAT, [1, 2, 3, 3, 3])], opset=20, ir=9)
    r = check_model(m)
    assert "5-D GridSample" in _errors(r, "trt10") and "5-D GridSample" in _errors(r, "trt11")
    assert "needs TensorRT >= 8.6" in _errors(r, "trt8.5")
    assert "opset 20 > 17" in _errors(r, "trt8.5")
    m4 = _model([helper.make_node("GridSample", ["x", "g"], ["y"])],
                [_vi("x", TensorProto.FLOAT, [1, 2, 4, 4]), _vi("g", TensorProto.FLOAT, [1, 3, 3, 2])],
                [_vi("y", TensorProto.FLOAT, [1, 2, 3, 3])], opset=17)
    assert check_model(m4).ok("trt10") and not check_model(m4).ok("trt8.5")


def test_compat_flags_3d_conv_transpose_and_new_ir():
    w = helper.make_tensor("w", TensorProto.FLOAT, [2, 2, 2, 2, 2], [0.1] * 32)
    m = _model([helper.make_node("ConvTranspose", ["x", "w"], ["y"], strides=[2, 2, 2])],
               [_vi("x", TensorProto.FLOAT, [1, 2, 4, 4, 4])],
               [_vi("y", TensorProto.FLOAT, [1, 2, 8, 8, 8])], ir=14, inits=[w])
    r = check_model(m)
    for t in ("trt8.5", "trt10", "trt11"):
        assert "3-D ConvTranspose" in _errors(r, t)
    assert "IR version 14 > 8" in _errors(r, "trt8.5")
    assert "onnxruntime 1.31 cannot read" in _errors(r, "onnxruntime")
    assert "FAILS" in r.table()
    with pytest.raises(ValueError, match="would not build"):
        r.raise_if_errors()


def test_compat_flags_int64_io_and_unknown_ops():
    m = _model([helper.make_node("Mod", ["x", "x"], ["y"])], [_vi("x", TensorProto.INT64, [3])],
               [_vi("y", TensorProto.INT64, [3])])
    r = check_model(m)
    assert "type i64" in _errors(r, "trt8.5") and "type i64" not in _errors(r, "trt10")
    assert "not in the TensorRT support table" in _errors(r, "trt10")


# ----------------------------------------------------------------------------- TensorRT

def test_trt_commands_say_tensorrt_is_missing(tmp_path, capsys):
    assert main(["trt", "build", str(tmp_path / "m.onnx"), "--out", str(tmp_path / "m.plan")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "TensorRT is not installed" in err[0]
    assert main(["trt", "run", str(tmp_path / "m.plan"), "--rig", "paper-train", "--images",
                 "a.png"]) == 3
    assert "TensorRT is not installed" in capsys.readouterr().err


class _Recorder:
    """A stand-in for the parts of the tensorrt module the builder touches; records calls."""

    def __init__(self, version, parse_ok=True, deserialise_ok=True):
        self.__version__ = version
        self.calls = []
        rec = self

        class Logger:
            WARNING = 2

            def __init__(self, level):
                pass

        class Flag:
            EXPLICIT_BATCH = 0
            STRONGLY_TYPED = 5

        class Parser:
            def __init__(self, network, logger):
                self.num_errors = 0 if parse_ok else 1

            def parse_from_file(self, path):
                rec.calls.append(("parse", path))
                return parse_ok

            def get_error(self, i):
                return "Unsupported operator IsInf"

        class Profile:
            def set_shape(self, name, lo, opt, hi):
                rec.calls.append(("profile", name, lo, hi))

        class Config:
            def set_memory_pool_limit(self, pool, size):
                rec.calls.append(("workspace", size))

            def set_flag(self, flag):
                rec.calls.append(("flag", flag))

            def add_optimization_profile(self, p):
                rec.calls.append(("add_profile",))

        class Builder:
            def __init__(self, logger):
                pass

            def create_network(self, flags):
                rec.calls.append(("network_flags", flags))
                return object()

            def create_builder_config(self):
                return Config()

            def create_optimization_profile(self):
                return Profile()

            def build_serialized_network(self, network, config):
                return b"PLAN" + version.encode()

        class Runtime:
            def __init__(self, logger):
                pass

            def deserialize_cuda_engine(self, data):
                return "engine" if deserialise_ok else None

        self.Logger, self.NetworkDefinitionCreationFlag = Logger, Flag
        self.OnnxParser, self.Builder, self.Runtime = Parser, Builder, Runtime
        self.MemoryPoolType = types.SimpleNamespace(WORKSPACE="workspace")
        self.BuilderFlag = types.SimpleNamespace(FP16="fp16")


def test_trt_build_branches_on_version(setup, tmp_path):
    from gijax.export.trt_engine import build_engine, load_engine

    onnx_path = setup["live"].path  # dynamic batch: needs an optimisation profile
    t8 = _Recorder("8.5.2.2")
    info = build_engine(onnx_path, str(tmp_path / "a.plan"), fp16=True, workspace_mb=512,
                        max_batch=4, trt=t8)
    assert ("network_flags", 1) in t8.calls and ("flag", "fp16") in t8.calls
    assert ("workspace", 512 << 20) in t8.calls
    assert ("profile", "images", (1, 3, 128, 128, 3), (4, 3, 128, 128, 3)) in t8.calls
    assert "--fp16" in info["trtexec"] and "--memPoolSize=workspace:512" in info["trtexec"]
    assert "--maxShapes=images:4x3x128x128x3" in info["trtexec"]
    assert (tmp_path / "a.plan").read_bytes() == b"PLAN8.5.2.2"
    assert json.loads((tmp_path / "a.plan.json").read_text())["tensorrt"] == "8.5.2.2"

    t10 = _Recorder("10.3.0")
    build_engine(onnx_path, str(tmp_path / "b.plan"), fp16=True, trt=t10)
    assert ("network_flags", 0) in t10.calls and ("flag", "fp16") in t10.calls

    t11 = _Recorder("11.0.1")
    with pytest.raises(ValueError, match="no FP16 builder flag"):
        build_engine(onnx_path, str(tmp_path / "c.plan"), fp16=True, trt=t11)
    info = build_engine(onnx_path, str(tmp_path / "c.plan"), trt=t11)
    assert ("network_flags", 1 << 5) in t11.calls and not any(c[0] == "flag" for c in t11.calls)
    assert "--stronglyTyped" in info["trtexec"] and "--fp16" not in info["trtexec"]

    with pytest.raises(ValueError, match="could not parse.*IsInf"):
        build_engine(onnx_path, str(tmp_path / "d.plan"), trt=_Recorder("8.5.1", parse_ok=False))
    # Engines of another TensorRT version: from the build record, and from the runtime itself.
    with pytest.raises(ValueError, match="built with TensorRT 8.5.2.2; this is TensorRT 10.3"):
        load_engine(str(tmp_path / "a.plan"), trt=_Recorder("10.3.0"))
    (tmp_path / "a.plan.json").unlink()
    with pytest.raises(ValueError, match="cannot deserialise"):
        load_engine(str(tmp_path / "a.plan"), trt=_Recorder("10.3.0", deserialise_ok=False))
    assert load_engine(str(tmp_path / "a.plan"), trt=_Recorder("8.5.2.2")) == "engine"


def test_cli_export_preset_validates_and_reports(tmp_path, capsys):
    cfg_file = tmp_path / "tiny.json"
    cfg_file.write_text(json.dumps({k: list(v) if isinstance(v, tuple) else v
                                    for k, v in dataclasses.asdict(TINY).items()}))
    out = tmp_path / "cli.onnx"
    code = main(["export", "--preset", str(cfg_file), "--rig", "paper-train", "--out", str(out),
                 "--batch", "2"])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "UNTRAINED" in text and "OK" in text and "TensorRT 8.5 (JetPack 5): OK" in text
    assert _session(out).get_inputs()[0].shape == [2, 3, 128, 128, 3]
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert "UNTRAINED" in meta["gijax.source"]
    # An --out that is a folder is refused in one line naming it, before the export runs.
    code = main(["export", "--preset", str(cfg_file), "--rig", "paper-train", "--out",
                 str(tmp_path), "--batch", "2"])
    captured = capsys.readouterr()
    err = [ln for ln in captured.err.splitlines() if ln.strip()]
    assert code != 0 and len(err) == 1 and f"--out {tmp_path} is a folder" in err[0], err
    assert "exporting" not in captured.out
    # A panorama the export could not trace (its sides, or memory for --batch samples) is
    # refused in one line before the export.
    code = main(["export", "--preset", str(cfg_file), "--rig", "paper-train", "--out",
                 str(tmp_path / "big.onnx"), "--panorama-size", "40000x160000"])
    captured = capsys.readouterr()
    assert code == 1 and "--panorama-size 40000x160000 (rows x columns) has a side beyond" \
        in captured.err and "exporting" not in captured.out
    assert not (tmp_path / "big.onnx").exists()


def test_predict_cli_onnx_backend_matches_the_predictor(setup, tmp_path):
    import cv2

    s = setup
    paths = []
    images = np.clip(np.asarray(s["images"][0]) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    for i, im in enumerate(images):
        paths.append(str(tmp_path / f"cam{i}.png"))
        cv2.imwrite(paths[-1], np.ascontiguousarray(im[..., ::-1]))
    out = tmp_path / "pred"
    code = main(["predict", "--backend", "onnx", "--onnx", str(s["baked"].path), "--rig",
                 "paper-train", "--images", *paths, "--out", str(out)])
    assert code == 0
    direct = OnnxPredictor(s["baked"].path, providers=["CPUExecutionProvider"]).predict(
        s["rig"], images, None)
    written = np.load(out / "distance.npy")
    # Invalid pixels are NaN in the file, as for every method (NaN compares equal here).
    want = np.where(direct["valid"], direct["distance"], np.nan)
    np.testing.assert_allclose(written, want, rtol=1e-5)
    assert (out / "points.ply").stat().st_size > 100


def test_onnx_predictor_follows_the_image_size_policy(setup):
    """Images of the rig's aspect at any size are resized to the exported size, with a note;
    another aspect is refused (the policy of the JAX model and the baseline)."""
    import cv2

    s = setup
    pred = OnnxPredictor(s["baked"].path, providers=["CPUExecutionProvider"])
    small = np.asarray(s["images"][0], np.float32)               # the exported 128 x 128
    big = np.stack([cv2.resize(im, (256, 256), interpolation=cv2.INTER_LINEAR) for im in small])
    notes = []
    out = pred.predict(s["rig"], big, None, log=notes.append)
    assert any("resized to 128 x 128" in n for n in notes), notes
    assert out["inv_distance"].shape == TINY.output_hw
    assert out["panorama"].shape == TINY.output_hw
    direct = pred.predict(s["rig"], small, None)
    # Shrinking a 2x bilinear enlargement by area averaging nearly restores the images.
    assert np.nanmean(np.abs(out["inv_distance"] - direct["inv_distance"])) < 0.05
    with pytest.raises(ValueError, match="same aspect ratio"):
        pred.predict(s["rig"], big[:, :200], None)


LOW_MEMORY_RUN = """
import sys
import numpy as np
from gijax.export.ort_session import make_session
feed = dict(np.load(sys.argv[2]))
sess = make_session(sys.argv[1], ["CPUExecutionProvider"], memory="low")
np.save(sys.argv[3], sess.run(["inv_distance"], feed)[0])
print("jax" in sys.modules)
"""


def test_low_memory_session_matches_jax_without_importing_it(setup, tmp_path):
    """The 'low' profile (no arena, no constant folding, fixed mmap threshold) runs in a fresh
    process that imports onnxruntime and not JAX, and gives JAX's numbers."""
    import subprocess
    import sys

    from gijax.export.ort_session import session_options

    s = setup
    feed = tmp_path / "feed.npz"
    np.savez(feed, images=np.asarray(s["images"], np.float32),
             masks=np.asarray(s["masks"], np.float32))
    got = tmp_path / "inv.npy"
    proc = subprocess.run([sys.executable, "-c", LOW_MEMORY_RUN, str(s["baked"].path),
                           str(feed), str(got)], capture_output=True, text=True, check=True)
    assert proc.stdout.strip() == "False"
    np.testing.assert_allclose(np.load(got)[0], s["ref"]["inv_distance"][0], atol=1e-4, rtol=0)
    opts, disabled = session_options("low")
    assert not opts.enable_cpu_mem_arena and not opts.enable_mem_pattern
    assert disabled == ["ConstantFolding"]
    opts, disabled = session_options("lean")
    assert opts.enable_cpu_mem_arena and disabled == ["ConstantFolding"]
    opts, disabled = session_options("default")
    assert opts.enable_cpu_mem_arena and disabled == []
    with pytest.raises(ValueError, match="memory profile must be one of.*found 'tiny'"):
        session_options("tiny")


def test_isolated_onnxruntime_child_reports_memory_without_jax(setup):
    """gijax bench's onnxruntime child: a fresh process, no JAX, its peak resident set."""
    from gijax.bench.isolated import run_child

    path = str(setup["baked"].path)
    row = run_child(["ort", path, "--memory", "low", "--reps", "1"])
    assert row["memory"] == "low" and row["imported_jax"] is False
    assert 0 < row["peak_gb_imports"] <= row["peak_gb_session"] <= row["peak_gb"] < 2.0
    assert row["ort_s"] > 0
    with pytest.raises(RuntimeError, match="exit status"):
        run_child(["ort", path + ".missing", "--reps", "1"])


def test_trt_build_strongly_typed_follows_the_file_and_refuses_contradictions(setup, tmp_path,
                                                                            capsys):
    """On 10.x an fp16 or int8 (Q/DQ) file builds strongly typed by default (creation flag 5,
    no builder flag, '--stronglyTyped' in the trtexec line), a float32 file weakly typed;
    --stronglyTyped with --fp16, on 8.x, and --no-stronglyTyped on 11.x are refused in one
    line before the builder is touched."""
    from gijax.export.precision import plan_fp16
    from gijax.export.trt_engine import build_engine, typed_precision

    fp32 = str(setup["baked"].path)
    proto = onnx.load(fp32)
    plan_fp16(proto)
    fp16 = str(tmp_path / "fp16.onnx")
    onnx.save_model(proto, fp16)
    scale = helper.make_tensor("s", TensorProto.FLOAT, [], [0.1])
    zero = helper.make_tensor("z", TensorProto.INT8, [], [0])
    qdq = _model([helper.make_node("QuantizeLinear", ["x", "s", "z"], ["q"]),
                  helper.make_node("DequantizeLinear", ["q", "s", "z"], ["y"])],
                 [_vi("x", TensorProto.FLOAT, [4])], [_vi("y", TensorProto.FLOAT, [4])],
                 inits=[scale, zero])
    int8 = str(tmp_path / "int8.onnx")
    onnx.save_model(qdq, int8)
    assert [typed_precision(p) for p in (fp32, fp16, int8)] == ["fp32", "fp16", "int8"]

    strong = ("network_flags", 1 << 5)
    for path, expect in ((fp16, True), (int8, True), (fp32, False)):
        t10 = _Recorder("10.3.0")
        info = build_engine(path, str(tmp_path / "e.plan"), trt=t10)
        assert info["strongly_typed"] is expect
        assert [c for c in t10.calls if c[0] == "network_flags"] == [
            ("network_flags", 1 << 5 if expect else 0)]
        assert not any(c[0] == "flag" for c in t10.calls)
        assert ("--stronglyTyped" in info["trtexec"]) is expect
        assert json.loads((tmp_path / "e.plan.json").read_text())["strongly_typed"] is expect
    # Asked for explicitly: a float32 file strongly typed; the FP16 flag keeps weak typing.
    t10 = _Recorder("10.3.0")
    assert build_engine(fp32, str(tmp_path / "f.plan"), strongly_typed=True,
                        trt=t10)["strongly_typed"] and strong in t10.calls
    t10 = _Recorder("10.3.0")
    info = build_engine(fp16, str(tmp_path / "g.plan"), fp16=True, trt=t10)
    assert ("network_flags", 0) in t10.calls and ("flag", "fp16") in t10.calls
    assert "--fp16" in info["trtexec"] and "--stronglyTyped" not in info["trtexec"]

    for version, kw, match in (("10.3.0", dict(strongly_typed=True, fp16=True), "contradict"),
                               ("8.5.2", dict(strongly_typed=True), "no strongly typed mode"),
                               ("11.0.1", dict(strongly_typed=False), "always strongly|every "
                                                                     "network strongly")):
        rec = _Recorder(version)
        with pytest.raises(ValueError, match=match):
            build_engine(fp16, str(tmp_path / "h.plan"), trt=rec, **kw)
        assert rec.calls == [] and not (tmp_path / "h.plan").exists()
    # The command line refuses the contradiction even where TensorRT is not installed.
    assert main(["trt", "build", fp16, "--out", str(tmp_path / "i.plan"), "--stronglyTyped",
                 "--fp16"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--stronglyTyped and --fp16 contradict" in err[0]


# --------------------------------------------------------------- jax2onnx's graph lookups

def _lookup_graph():
    """An ONNX-IR graph with an input, an initializer, two nodes in it, one removed and one
    never added: every case the converter's lookups answer."""
    import onnx_ir as ir

    x = ir.Value(name="x")
    w = ir.Value(name="w", const_value=ir.tensor(np.ones(2, np.float32)))
    a = ir.Node("", "Relu", [x])
    b = ir.Node("", "Add", [a.outputs[0], w])
    gone = ir.Node("", "Neg", [x])
    loose = ir.Node("", "Abs", [x])
    graph = ir.Graph([x], [b.outputs[0]], nodes=[a, b, gone], initializers=[w])
    graph.remove(gone)
    # A value named like a node's output but not that output (the name match of the original).
    twin = ir.Value(name=a.outputs[0].name)
    values = [x, w, a.outputs[0], b.outputs[0], gone.outputs[0], loose.outputs[0], twin, None]
    return graph, [a, b], values


def test_fast_converter_lookups_answer_as_the_originals():
    """Each patched lookup gives the original's answer on every kind of value: inputs,
    initializers, outputs of nodes in the graph, of a removed node, of a node never added,
    a same-named twin, and None; the node lists include a stale one that still holds the
    removed node (as an optimisation pass's snapshot does)."""
    from jax2onnx.converter import optimizer_graph_utils, output_binding

    from gijax.export.converter_lookups import fast_lookups

    graph, kept, values = _lookup_graph()
    ctx = types.SimpleNamespace(builder=types.SimpleNamespace(
        nodes=graph, inputs=list(graph.inputs), initializers=list(graph.initializers.values())))
    removed = values[4].producer()
    node_lists = [list(graph), kept + [removed], tuple(kept), []]
    original_connected = output_binding._value_is_graph_connected
    original_producer = optimizer_graph_utils._producer_node
    expected_connected = [original_connected(ctx, v) for v in values if v is not None]
    expected_producer = [[original_producer(n, v) for v in values] for n in node_lists]
    assert expected_connected == [True, True, True, True, False, False, True]
    assert expected_producer[1][4] is removed          # the stale list still finds it
    with fast_lookups() as patched:
        assert patched
        assert output_binding._value_is_graph_connected is not original_connected
        got_connected = [output_binding._value_is_graph_connected(ctx, v)
                         for v in values if v is not None]
        got_producer = [[optimizer_graph_utils._producer_node(n, v) for v in values]
                        for n in node_lists]
    assert got_connected == expected_connected
    assert all(g is e for gs, es in zip(got_producer, expected_producer)
               for g, e in zip(gs, es))
    assert output_binding._value_is_graph_connected is original_connected
    assert optimizer_graph_utils._producer_node is original_producer


def test_fast_converter_lookups_restore_on_error_and_stand_aside_for_other_internals(
        monkeypatch):
    from jax2onnx.converter import ir_optimizations, optimizer_graph_utils

    from gijax.export import converter_lookups

    original = optimizer_graph_utils._producer_node
    with pytest.raises(RuntimeError, match="inside"):
        with converter_lookups.fast_lookups():
            assert ir_optimizations._producer_node is not original
            raise RuntimeError("inside")
    assert ir_optimizations._producer_node is original

    def other(nodes, value, extra=None):       # a jax2onnx whose signature changed
        return None

    monkeypatch.setattr(optimizer_graph_utils, "_producer_node", other)
    with converter_lookups.fast_lookups() as patched:
        assert not patched
        assert optimizer_graph_utils._producer_node is other
        assert ir_optimizations._producer_node is original


def test_export_with_fast_lookups_writes_the_same_bytes(setup, tmp_path, monkeypatch):
    """The baked export of the module's network, once more with the converter's own lookups,
    is byte for byte the file the patched converter wrote."""
    import contextlib

    from gijax.export import onnx_export

    s = setup
    monkeypatch.setattr(onnx_export, "fast_lookups", lambda: contextlib.nullcontext(False))
    plain = export_onnx(s["model"], s["rig"], CAND, tmp_path / "plain.onnx")
    assert (Path(plain.path).read_bytes() == Path(s["baked"].path).read_bytes())
