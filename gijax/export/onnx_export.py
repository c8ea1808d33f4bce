"""Export the whole inference graph to ONNX with jax2onnx, legalise it for TensorRT, validate it.

Graph inputs (float32, B = batch, N cameras, (h, w) = the model's image size, i.e. the rig's
calibrated size times ``config.image_scale``):

=================  ==================  ===================================================
name               shape               meaning
=================  ==================  ===================================================
``images``         (B, N, h, w, 3)     raw fisheye images, RGB in [0, 1]
``masks``          (B, N, h, w)        per-pixel validity, 1 = sees the world
``intrinsics``     (N, P)              rig-as-input only: camera parameters then ``fov``
``rotations``      (N, 3, 3)           rig-as-input only: camera-to-rig rotations
``translations``   (N, 3)              rig-as-input only: camera centres, metres
``reference``      (3,)                rig-as-input only: panorama centre, metres
``candidates``     (D,)                rig-as-input only: ascending distances, metres
=================  ==================  ===================================================

Outputs: ``inv_distance`` (B, H, W) 1/m, ``distance`` (B, H, W) m, ``entropy`` (B, H, W)
nats (uncertainty) and ``valid`` (B, H, W) float32 in {0, 1}.

Default mode bakes the rig and the candidates in: the sampling grids are computed once here and
stored as constants, so the engine only gathers. With ``rig_as_input=True`` intrinsics, poses,
reference and candidates are inputs and the grids are computed in the graph (camera model and
image size stay fixed), so a re-calibrated rig needs no new export.

After jax2onnx the graph is legalised (see :func:`legalise`): stale intermediate shape
annotations are dropped, integer ``Clip`` becomes ``Max``/``Min`` and ``IsInf`` becomes
``Equal(Abs(x), inf)`` (TensorRT 8.5 has neither integer Clip nor IsInf), and the IR version is
lowered to the oldest one that carries the opset (TensorRT 8.5's parser reads IR <= 8).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
import os
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from gijax.export.converter_lookups import fast_lookups
from gijax.export.graph import intrinsics_layout, rig_from_arrays
from gijax.export.precision import (DEFAULT_CALIBRATION_SCENES, PRECISIONS, plan_fp16,
                                    quantize_int8)
from gijax.geometry.panorama import Panorama
from gijax.geometry.panorama_frame import panorama_rotation
from gijax.geometry.rig import Rig, scale_rig
from gijax.io.paths import atomic_path
from gijax.model import (OmniStereoNet, check_model_candidates, model_grids, model_panorama,
                         on_fisheye_images, with_conv3d)
from gijax.sweep.grids import SurrogateMaps, SweepGrids, surrogate_resampling

IMAGES, MASKS = "images", "masks"
RIG_INPUTS = ("intrinsics", "rotations", "translations", "reference", "candidates")
OUTPUTS = ("inv_distance", "distance", "entropy", "valid")
DEFAULT_OPSET = 17
# jax2onnx 0.17 writes opsets up to 23; TensorRT 8.5 reads up to 17.
SUPPORTED_OPSETS = range(13, 24)
META_PREFIX = "gijax."


@dataclasses.dataclass(frozen=True)
class ExportResult:
    """What :func:`export_onnx` wrote: the file, its inputs and outputs (name -> shape; a
    dynamic batch is the string 'B') and the metadata stored in the file."""

    path: str
    inputs: dict
    outputs: dict
    metadata: dict


def rig_at_model_size(config, rig: Rig) -> Rig:
    """The rig at the model's image size (intrinsics scaled by ``config.image_scale``)."""
    return rig if config.image_scale == 1.0 else scale_rig(rig, config.image_scale)


def check_export_inputs(model: OmniStereoNet, rig: Rig, candidates) -> None:
    """ValueError for a rig the model cannot use or a wrong candidate list."""
    cfg = model.config
    if cfg.cost_volume == "concat" and rig.num_cameras != cfg.num_cameras:
        raise ValueError(f"model {cfg.name!r} concatenates exactly {cfg.num_cameras} cameras (it "
                         f"was trained for that count); the rig has {rig.num_cameras}")
    if rig.num_cameras < 2:
        raise ValueError(f"stereo needs at least 2 cameras; the rig has {rig.num_cameras}")
    check_model_candidates(cfg, candidates)


def eval_view(model: OmniStereoNet) -> OmniStereoNet:
    """A copy of ``model`` in eval mode (BatchNorm running statistics); ``model`` is unchanged."""
    graphdef, state = nnx.split(model)
    view = nnx.merge(graphdef, state)
    view.eval()
    return view


def _input_specs(cfg, rig: Rig, batch, rig_as_input: bool):
    cam = rig.cameras[0]
    n, h, w = rig.num_cameras, cam.height, cam.width
    specs = {IMAGES: (batch, n, h, w, 3), MASKS: (batch, n, h, w)}
    if rig_as_input:
        specs.update(intrinsics=(n, len(intrinsics_layout(rig))), rotations=(n, 3, 3),
                     translations=(n, 3), reference=(3,), candidates=(cfg.num_candidates,))
    return specs


@functools.partial(jax.jit, static_argnums=(0, 3))
def _grids_jit(config, rig: Rig, candidates, pano: Panorama) -> tuple[SurrogateMaps, SweepGrids]:
    return surrogate_resampling(rig, config.surrogate_hw), model_grids(config, rig, candidates,
                                                                       pano)


def _outputs(out: dict) -> tuple:
    # Validity leaves as float32: TensorRT 8.x has no boolean network outputs.
    out = dict(out, valid=out["valid"].astype(jnp.float32))
    return tuple(out[k] for k in OUTPUTS)


def build_function(model: OmniStereoNet, rig: Rig, candidates, rig_as_input: bool,
                   pano: Panorama | None = None):
    """The exported function: positional inputs in the order of the module docstring, a tuple
    of :data:`OUTPUTS`. ``rig`` is at the model's image size; ``model`` in eval mode; ``pano``
    the output panorama (default the model's own), oriented by ``rig``'s panorama frame, which
    is baked in even when the rest of the rig is an input."""
    cfg = model.config
    pano = model_panorama(cfg) if pano is None else pano
    if not rig_as_input:
        cand = jnp.asarray(candidates, jnp.float32)
        # Evaluated once, eagerly: the engine receives the grids as constants.
        maps, grids = jax.tree_util.tree_map(lambda a: jnp.asarray(np.asarray(a)),
                                             _grids_jit(cfg, rig, cand, pano))

        def fn(images, masks):
            return _outputs(on_fisheye_images(model, images, masks, maps, grids))

        return fn
    intrinsics_layout(rig)  # one camera model and size, or a clear error

    def fn(images, masks, intrinsics, rotations, translations, reference, cand):
        run_rig = rig_from_arrays(rig, intrinsics, rotations, translations, reference)
        return _outputs(on_fisheye_images(model, images, masks,
                                     surrogate_resampling(run_rig, cfg.surrogate_hw),
                                     model_grids(cfg, run_rig, cand, pano)))

    return fn


def export_onnx(model: OmniStereoNet, rig: Rig, candidates, path: str | os.PathLike, *,
                opset: int = DEFAULT_OPSET, batch: int = 1, dynamic_batch: bool = False,
                rig_as_input: bool = False, extra_metadata: dict | None = None,
                pano: Panorama | None = None, precision: str = "fp32",
                calibration_scenes: int = DEFAULT_CALIBRATION_SCENES) -> ExportResult:
    """Export ``model`` for ``rig`` (at its calibrated size) to the ONNX file ``path``.

    Args:
      model: a trained (or, for testing, freshly initialised) network; exported in eval mode.
      rig: the camera rig; scaled to the model's image size here.
      candidates: (D,) ascending metres (baked in, or the default fed by the predictors).
      path: output file (written under a temporary name, then renamed).
      opset: ONNX opset (17 reads in TensorRT 8.5 and later).
      batch: the static batch size (ignored with ``dynamic_batch``).
      dynamic_batch: the batch axis of images, masks and outputs is symbolic ('B').
      rig_as_input: intrinsics, poses, reference and candidates become graph inputs.
      extra_metadata: more string metadata to store (e.g. the checkpoint path).
      pano: the output panorama (default the model's own, :func:`gijax.model.model_panorama`),
        oriented by ``rig``'s panorama frame (baked into the file).
      precision: 'fp32', or 'fp16' for the precision plan of :mod:`gijax.export.precision`
        (float16 feature extractor and U-Net, float32 sampling and regression; the inputs
        and outputs stay float32), or 'int8' for that plan quantised (QDQ, per-channel int8
        convolution weights in the islands, everything else float32 and unquantised).
      calibration_scenes: int8 only: rendered scenes of ``rig`` the activation ranges are
        calibrated on (seeds 1000, 1001, ...).

    Returns:
      an :class:`ExportResult`.
    """
    import onnx
    from jax2onnx import to_onnx

    cfg = model.config
    if opset not in SUPPORTED_OPSETS:
        raise ValueError(f"opset must be in {SUPPORTED_OPSETS.start}..{SUPPORTED_OPSETS.stop - 1}"
                         f"; found {opset}")
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}; found "
                         f"{precision!r}")
    if precision == "int8" and (int(calibration_scenes) != calibration_scenes
                                or calibration_scenes < 1):
        raise ValueError(f"calibration_scenes must be a positive integer; found "
                         f"{calibration_scenes}")
    if not dynamic_batch and (int(batch) != batch or batch < 1):
        raise ValueError(f"batch must be a positive integer; found {batch}")
    check_export_inputs(model, rig, candidates)
    run_rig = rig_at_model_size(cfg, rig)
    pano = model_panorama(cfg) if pano is None else pano
    view = eval_view(with_conv3d(model, "native"))  # one Conv node per 3-D conv
    fn = build_function(view, run_rig, candidates, rig_as_input, pano)
    specs = _input_specs(cfg, run_rig, "B" if dynamic_batch else int(batch), rig_as_input)
    names = list(specs)
    quiet = logging.getLogger("onnx_ir")
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # per-constant serialisation notes are not actionable
    try:
        with warnings.catch_warnings(), fast_lookups():
            warnings.simplefilter("ignore", DeprecationWarning)  # jax2onnx's flax accessors
            proto = to_onnx(fn, list(specs.values()), opset=opset, model_name=f"gijax_{cfg.name}",
                            input_names=names, output_names=list(OUTPUTS))
    finally:
        # jax2onnx swaps primitives while tracing; jitted functions traced meanwhile must not
        # be reused by later JAX calls in this process.
        jax.clear_caches()
        quiet.setLevel(level)
    legalise(proto)
    metadata = export_metadata(cfg, run_rig, candidates, rig_as_input, dynamic_batch, pano)
    if precision != "fp32":  # an fp32 file stays byte-for-byte what it was
        metadata["precision"] = precision
    if precision == "fp16":
        metadata["fp16_islands"] = json.dumps(plan_fp16(proto)["islands"])
    if precision == "int8":
        proto, islands = _quantized(proto, cfg, rig, run_rig, candidates, rig_as_input,
                                    int(calibration_scenes))
        metadata.update(int8_islands=json.dumps(islands),
                        calibration=f"{int(calibration_scenes)} rendered scenes, seeds 1000+")
    metadata.update({k: str(v) for k, v in (extra_metadata or {}).items()})
    for key, value in metadata.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = META_PREFIX + key, value
    onnx.checker.check_model(proto, full_check=True)
    _save_atomic(proto, Path(path))
    inputs = {k: list(v) for k, v in specs.items()}
    bdim = "B" if dynamic_batch else int(batch)
    outputs = {k: [bdim, *pano.shape] for k in OUTPUTS}
    return ExportResult(str(path), inputs, outputs, metadata)


def _quantized(proto, cfg, rig: Rig, run_rig: Rig, candidates, rig_as_input: bool,
               scenes: int):
    """``proto`` quantised to int8 by :func:`gijax.export.precision.quantize_int8`, calibrated
    on ``scenes`` rendered samples of ``rig``; returns (the new proto, its islands)."""
    import tempfile

    import onnx
    from onnx import helper

    from gijax.export.ort_predict import rig_feed

    feeds = []
    for i in range(scenes):
        images, masks = rendered_inputs(cfg, rig, seed=1000 + i)
        feed = {IMAGES: images, MASKS: masks}
        if rig_as_input:
            feed.update(rig_feed(run_rig, candidates))
        feeds.append(feed)
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "fp32.onnx", Path(tmp) / "int8.onnx"
        onnx.save_model(proto, str(src))
        info = quantize_int8(src, dst, feeds)
        quantized = onnx.load(str(dst))
    del quantized.metadata_props[:]
    opsets = [helper.make_opsetid(o.domain, o.version) for o in quantized.opset_import]
    quantized.ir_version = min(quantized.ir_version, helper.find_min_ir_version_for(opsets))
    return quantized, info["islands"]


def export_metadata(cfg, run_rig: Rig, candidates, rig_as_input: bool,
                    dynamic_batch: bool, pano: Panorama | None = None) -> dict:
    """String metadata stored in the file (read back by :mod:`gijax.export.ort_predict`)."""
    cam = run_rig.cameras[0]
    pano = model_panorama(cfg) if pano is None else pano
    return {
        "panorama": json.dumps({
            "height": pano.height, "width": pano.width, "lat_min_rad": pano.lat_min,
            "lat_max_rad": pano.lat_max,
            "rotation_panorama_to_rig": np.asarray(panorama_rotation(run_rig),
                                                   np.float64).tolist()}),
        "config": json.dumps({k: list(v) if isinstance(v, tuple) else v
                              for k, v in dataclasses.asdict(cfg).items()}),
        "mode": "rig_as_input" if rig_as_input else "baked",
        "dynamic_batch": json.dumps(bool(dynamic_batch)),
        "candidates_m": json.dumps([float(c) for c in np.asarray(candidates, np.float64)]),
        "num_cameras": str(run_rig.num_cameras),
        "camera_model": cam.MODEL,
        "image_hw": json.dumps([cam.height, cam.width]),
        "image_scale": repr(float(cfg.image_scale)),
        "camera_names": json.dumps(list(run_rig.names)),
        "intrinsics_layout": json.dumps(list(intrinsics_layout(run_rig)))
        if rig_as_input else "",
    }


def read_metadata(proto) -> dict:
    """The gijax metadata of an ONNX model proto (keys without the prefix)."""
    return {p.key[len(META_PREFIX):]: p.value for p in proto.metadata_props
            if p.key.startswith(META_PREFIX)}


def _save_atomic(proto, path: Path) -> None:
    import onnx

    with atomic_path(path) as tmp:
        onnx.save_model(proto, str(tmp))


# ----------------------------------------------------------------------------- legalisation

def _dtype_map(proto) -> dict:
    """Tensor name -> ONNX element type, from shape inference over the whole graph."""
    import onnx

    inferred = onnx.shape_inference.infer_shapes(proto, strict_mode=False)
    g = inferred.graph
    types = {v.name: v.type.tensor_type.elem_type
             for v in list(g.value_info) + list(g.input) + list(g.output)}
    types.update({t.name: t.data_type for t in g.initializer})
    for node in g.node:
        if node.op_type == "Constant":
            for a in node.attribute:
                if a.name == "value":
                    types[node.output[0]] = a.t.data_type
    return types


_INTEGER_TYPES = {2, 3, 4, 5, 6, 7, 12, 13}  # uint8, int8, uint16, int16, int32, int64, uint32/64


def legalise(proto) -> None:
    """Rewrite ``proto`` in place for TensorRT and onnxruntime (see the module docstring)."""
    import onnx
    from onnx import helper

    g = proto.graph
    del g.value_info[:]
    types = _dtype_map(proto)
    new_nodes = []
    counter = 0

    def fresh(stem):
        nonlocal counter
        counter += 1
        return f"{stem}__legal{counter}"

    for node in g.node:
        if node.op_type == "Clip" and types.get(node.input[0]) in _INTEGER_TYPES:
            x = node.input[0]
            lo = node.input[1] if len(node.input) > 1 else ""
            hi = node.input[2] if len(node.input) > 2 else ""
            cur = x
            if lo:
                nxt = fresh(x) if hi else node.output[0]
                new_nodes.append(helper.make_node("Max", [cur, lo], [nxt], name=fresh("Max")))
                cur = nxt
            if hi:
                new_nodes.append(helper.make_node("Min", [cur, hi], [node.output[0]],
                                                  name=fresh("Min")))
            elif not lo:
                new_nodes.append(helper.make_node("Identity", [x], [node.output[0]]))
            continue
        if node.op_type == "IsInf":
            attrs = {a.name: a.i for a in node.attribute}
            if attrs.get("detect_positive", 1) and attrs.get("detect_negative", 1):
                x = node.input[0]
                dtype = types.get(x, onnx.TensorProto.FLOAT)
                inf = fresh("inf")
                g.initializer.append(helper.make_tensor(inf, dtype, [], [float("inf")]))
                absx = fresh("abs")
                new_nodes.append(helper.make_node("Abs", [x], [absx], name=fresh("Abs")))
                new_nodes.append(helper.make_node("Equal", [absx, inf], [node.output[0]],
                                                  name=fresh("Equal")))
                continue
        new_nodes.append(node)
    del g.node[:]
    g.node.extend(new_nodes)
    opsets = [helper.make_opsetid(o.domain, o.version) for o in proto.opset_import]
    proto.ir_version = min(proto.ir_version, helper.find_min_ir_version_for(opsets))


# ----------------------------------------------------------------------------- validation

def export_panorama(meta: dict, config) -> Panorama:
    """The output panorama recorded in an export's metadata (files without one: the model's
    own hemisphere)."""
    if "panorama" not in meta:
        return model_panorama(config)
    doc = json.loads(meta["panorama"])
    return Panorama(int(doc["height"]), int(doc["width"]), float(doc["lat_min_rad"]),
                    float(doc["lat_max_rad"]))


def jax_reference(model: OmniStereoNet, rig: Rig, images, masks, candidates,
                  pano: Panorama | None = None) -> dict:
    """The same outputs computed by JAX (the network on the images' surrogates, jitted), for
    parity checks. ``images`` (B, N, h, w, 3) float in [0, 1] at the model's image size, masks
    (B, N, h, w); ``rig`` at its calibrated size; ``pano`` the output panorama (default the
    model's own)."""
    cfg = model.config
    run_rig = rig_at_model_size(cfg, rig)
    cand = jnp.asarray(candidates, jnp.float32)

    @nnx.jit
    def run(v, im, m, c):
        return on_fisheye_images(v, im, m, surrogate_resampling(run_rig, cfg.surrogate_hw),
                            model_grids(cfg, run_rig, c, pano))

    out = run(eval_view(model), jnp.asarray(images, jnp.float32), jnp.asarray(masks, jnp.float32),
              cand)
    return {"inv_distance": np.asarray(out["inv_distance"]),
            "distance": np.asarray(out["distance"]),
            "entropy": np.asarray(out["entropy"]),
            "valid": np.asarray(out["valid"], np.float32)}


def rendered_inputs(config, rig: Rig, seed: int = 0, batch: int = 1) -> tuple:
    """(images (B, N, h, w, 3) float32 in [0, 1], masks (B, N, h, w) float32) rendered by
    :func:`gijax.render.render_sample` for the rig at the model's image size."""
    from gijax.render import render_sample

    run_rig = rig_at_model_size(config, rig)
    imgs, msks = [], []
    for i in range(batch):
        s = render_sample(run_rig, seed + i, pano=model_panorama(config))
        imgs.append(s["images"].astype(np.float32) / 255.0)
        msks.append(s["masks"].astype(np.float32))
    return np.stack(imgs), np.stack(msks)


def validate_export(path: str | os.PathLike, model: OmniStereoNet, rig: Rig, candidates,
                    images=None, masks=None, atol: float = 1e-4, seed: int = 0) -> dict:
    """Check an exported file: ONNX checker, then onnxruntime against the JAX model.

    Inputs default to a rendered sample. Returns {'max_abs_inv_distance', 'max_abs_entropy',
    'valid_mismatch', 'ok'}; ``ok`` is True when the inverse distance agrees within ``atol``
    (1/m) everywhere and the validity maps are equal.
    """
    import onnx

    from gijax.export.ort_predict import rig_feed
    from gijax.export.ort_session import make_session

    onnx.checker.check_model(str(path), full_check=True)
    sess = make_session(str(path))
    meta = read_metadata(onnx.load(str(path), load_external_data=False))
    batch = sess.get_inputs()[0].shape[0]
    if images is None:
        images, masks = rendered_inputs(model.config, rig, seed,
                                        batch if isinstance(batch, int) else 1)
    ref = jax_reference(model, rig, images, masks, candidates,
                        export_panorama(meta, model.config))
    feed = {IMAGES: np.asarray(images, np.float32), MASKS: np.asarray(masks, np.float32)}
    if meta.get("mode") == "rig_as_input":
        feed.update(rig_feed(rig_at_model_size(model.config, rig), candidates))
    got = dict(zip(OUTPUTS, sess.run(list(OUTPUTS), feed)))
    d_inv = float(np.max(np.abs(got["inv_distance"] - ref["inv_distance"])))
    d_ent = float(np.max(np.abs(got["entropy"] - ref["entropy"])))
    mismatch = int(np.sum(got["valid"] != ref["valid"]))
    return {"max_abs_inv_distance": d_inv, "max_abs_entropy": d_ent,
            "valid_mismatch": mismatch, "ok": bool(d_inv <= atol and mismatch == 0)}
