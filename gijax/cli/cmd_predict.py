"""``gijax predict``: distance panorama, colour maps and point cloud from fisheye images."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

HELP = "estimate the distance panorama of one set of fisheye images"
DESCRIPTION = """\
Run a model on one image per camera and write, under --out: distance.npy (float32 metres,
160 x 640 at paper size), valid.npy / valid.png (per-pixel validity: True / 255 where a
distance was estimated), inverse_distance.png (colour map with a colour bar in metres),
uncertainty.png (entropy of the candidate distribution), points.ply (coloured point cloud in
the rig frame) and prediction.json.

Invalid pixels (seen by too few cameras, e.g. masked out), for every method: NaN in
distance.npy, False / 0 in valid.npy / valid.png, black in both colour maps, no point in
points.ply; prediction.json gives valid_fraction and valid_pixels.

The model comes from a training run folder or an inference bundle (--ckpt), from an exported
ONNX file run by onnxruntime (--backend onnx --onnx FILE), or, for trying the pipeline, from a
preset with random weights (--preset; the outputs are then labelled UNTRAINED).
--method rtss runs the classical sphere-sweep stereo baseline instead (no model needed;
--rtss-preset picks RS-E16, RS-G16, RS-E32, RS-G32 or RS-E32-AD, the last with the
paper's 1x1 absolute-difference cost).

Candidates: 'train' (default) uses the training list (from the run folder; for a preset, the
preset's kind in closed form: EV or GI with the paper's baseline); 'spacing' is the paper's
list recomputed for the given rig (Table II): the closed-form GI list with the rig's camera
spacing as the baseline (same count, no retraining needed); 'rig' is gijax's extension,
rig-aware GI (equal mean pixel steps over the panorama's rays and the rig's cameras; on the
training rig it is close to EV, not to the released G16); 'ev' evenly spaced; or a file with
one distance in metres per line, or a JSON list.
"""


def register(subparsers) -> None:
    p = subparsers.add_parser("predict", help=HELP, description=DESCRIPTION,
                              formatter_class=__import__("argparse").RawDescriptionHelpFormatter)
    p.add_argument("--method", choices=("learned", "rtss"), default="learned",
                   help="learned network (default) or the classical RTSS baseline")
    p.add_argument("--rtss-preset", default="RS-E32", metavar="NAME",
                   help="RTSS configuration for --method rtss (default RS-E32)")
    p.add_argument("--backend", choices=("jax", "onnx"), default="jax",
                   help="run the learned model in JAX (default) or an exported ONNX file with "
                        "onnxruntime (CPU, or CUDA where available)")
    p.add_argument("--onnx", metavar="FILE", help="exported model for --backend onnx")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--ckpt", metavar="PATH", help="training run folder (config.json + "
                     "checkpoints)")
    src.add_argument("--preset", metavar="NAME|FILE", help="model preset (e.g. G16VV-cpu) or a "
                     "JSON file of ModelConfig fields, with random, UNTRAINED weights")
    p.add_argument("--rig", required=True, metavar="NAME|FILE",
                   help="built-in rig name (paper-train, paper-test1..3) or a rig / Kalibr / "
                        "basalt calibration file")
    p.add_argument("--images", required=True, nargs="+", metavar="IMAGE",
                   help="one fisheye image per camera, in the rig's camera order")
    p.add_argument("--masks", nargs="+", metavar="MASK",
                   help="optional validity masks per camera (non-zero = valid); default: the "
                        "rig's own masks")
    p.add_argument("--candidates", default="train", metavar="train|spacing|rig|ev|FILE",
                   help="distance candidates (see above); default: train")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--seed", type=int, default=0, help="initialisation seed for --preset")
    p.set_defaults(func=run)


def read_image(path: str, grey: bool = False) -> np.ndarray:
    import cv2

    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: no such image")
    img = cv2.imread(path, cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: not a readable image")
    if grey:
        return img
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    elif img.shape[-1] == 4:
        img = img[..., :3]
    if img.dtype == np.uint16:
        img = (img / 257.0 + 0.5).astype(np.uint8)
    return np.ascontiguousarray(img[..., ::-1])  # BGR -> RGB


def read_candidates(path: str) -> np.ndarray:
    """Distances (metres) from a candidate file: a JSON list or one number per line."""
    from gijax.cli.cmd_train import read_candidate_file

    return np.asarray(read_candidate_file(path), np.float64)


def resolve_candidates(spec: str, config, rig, train_candidates) -> tuple[np.ndarray, str]:
    """(candidates in metres, description) for --candidates ``spec``."""
    n = config.num_candidates
    if spec == "train":
        if train_candidates is not None:
            return np.asarray(train_candidates, np.float64), "training list"
        from gijax.candidates.closed_form import ev_candidates, gi_candidates

        fn = ev_candidates if config.candidates == "ev" else gi_candidates
        c = fn(n, config.d_min, config.d_max)
        return np.asarray(c, np.float64), f"{config.candidates.upper()} closed form"
    from gijax.candidates import RECOMPUTED, recomputed_candidates

    if spec in RECOMPUTED:
        c = recomputed_candidates(spec, n, rig, config.d_min, config.d_max)
        label = {"spacing": "the paper's GI at the rig's camera spacing",
                 "rig": "rig-aware GI (gijax extension)", "ev": "EV"}[spec]
        return np.asarray(c, np.float64), label
    return read_candidates(spec), f"from {spec}"


def preset_config(spec: str):
    """A preset name, or a JSON file holding ModelConfig fields -> ModelConfig."""
    from gijax.nn.presets import ModelConfig, get_preset

    if not spec.lower().endswith(".json"):
        return get_preset(spec)
    path = Path(spec)
    if not path.is_file():
        raise FileNotFoundError(f"{spec}: no such model configuration file")
    try:
        fields = json.loads(path.read_text())
        return ModelConfig(**{k: tuple(v) if isinstance(v, list) else v
                              for k, v in fields.items()})
    except (json.JSONDecodeError, TypeError) as exc:
        raise ValueError(f"{spec}: not a JSON object of ModelConfig fields ({exc})") from exc


def run(args) -> int:
    from gijax.io.rigfile import load_rig
    from gijax.model import create_model
    from gijax.io.paths import check_output_dir
    from gijax.predict import load_model, predict

    check_output_dir(args.out)
    rig = load_rig(args.rig)
    if len(args.images) != rig.num_cameras:
        raise ValueError(f"rig {args.rig!r} has {rig.num_cameras} cameras but "
                         f"{len(args.images)} images were given")
    if args.masks is not None and len(args.masks) != len(args.images):
        raise ValueError(f"{len(args.masks)} masks given for {len(args.images)} images")
    images = [read_image(p) for p in args.images]
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise ValueError(f"all images must have the same size; found {sorted(shapes)}")
    masks = None
    if args.masks is not None:
        masks = np.stack([(read_image(p, grey=True) > 0).astype(np.float32) for p in args.masks])
    if args.method == "rtss":
        return _run_rtss(args, rig, np.stack(images), masks)
    if args.backend == "onnx":
        return _run_onnx(args, rig, np.stack(images), masks)
    if not (args.ckpt or args.preset):
        raise ValueError("the learned method needs --ckpt RUN (or --preset NAME for an untrained "
                         "model)")
    if args.ckpt:
        model, train_cand = load_model(args.ckpt)
        label = f"{model.config.name} from {args.ckpt}"
    else:
        model, train_cand = create_model(preset_config(args.preset), seed=args.seed), None
        label = f"UNTRAINED {model.config.name} (random weights, seed {args.seed})"
    candidates, how = resolve_candidates(args.candidates, model.config, rig, train_cand)
    result = predict(model, rig, np.stack(images), masks, candidates)
    title = f"{label}; candidates: {how}"
    _report(result, rig, args.out, title)
    return 0


def _report(result: dict, rig, out: str, title: str) -> None:
    from gijax.predict import write_prediction

    paths = write_prediction(result, rig, out, title=title)
    print(title)
    valid = np.asarray(result["valid"], bool)
    median = (f"median {np.median(np.asarray(result['distance'])[valid]):.3f} m" if valid.any()
              else "no valid pixel")
    print(f"distance {result['distance'].shape}: {median}, valid {valid.mean() * 100:.1f} %")
    for kind, path in paths.items():
        print(f"  {kind:22s} {path}")


def _colours(rig, images: np.ndarray, masks, distance: np.ndarray) -> np.ndarray:
    import jax.numpy as jnp

    from gijax.predict import _point_colours
    from gijax.sweep.surrogate import as_float_image

    colour_rig = rig if masks is None else rig.replace(
        masks=tuple(jnp.asarray(m, jnp.float32) for m in masks))
    return np.asarray(_point_colours(colour_rig, as_float_image(images),
                                     jnp.asarray(np.nan_to_num(distance, nan=1.0))))


def _run_rtss(args, rig, images: np.ndarray, masks) -> int:
    """The classical baseline at the images' own size; the panorama is the paper's 160 x 640."""
    from gijax.baseline.rtss import get_rtss_preset, preset_candidates, rtss_predict_sample

    from gijax.geometry.rig import scale_rig

    config = get_rtss_preset(args.rtss_preset)
    cam = rig.cameras[0]
    if images.shape[1:3] != (cam.height, cam.width):
        # Images smaller than the calibration (e.g. the -cpu size): the same lens, resized.
        factor = images.shape[2] / cam.width
        rig = scale_rig(rig, factor)
        if images.shape[1:3] != (rig.cameras[0].height, rig.cameras[0].width):
            raise ValueError(f"images are {images.shape[1]} x {images.shape[2]}; the rig's "
                             f"cameras are {cam.height} x {cam.width} (another aspect ratio)")
    candidates = (preset_candidates(rig, config) if args.candidates == "train" else
                  resolve_candidates(args.candidates, config, rig, None)[0])
    sample = {"images": images}
    if masks is not None:
        sample["masks"] = masks
    result = rtss_predict_sample(rig, sample, args.rtss_preset, candidates=candidates)
    valid = np.asarray(result["valid"], bool)
    result = {
        # Invalid pixels are NaN here already; write_prediction applies the same convention
        # to every method's result.
        "inv_distance": np.asarray(result["inv_distance"], np.float32),
        "distance": np.asarray(result["distance"], np.float32),
        "valid": valid,
        # The baseline has no candidate distribution; its uncertainty map is left at zero.
        "entropy": np.zeros(valid.shape, np.float32),
        "candidates": np.asarray(candidates, np.float64),
    }
    result["colour"] = _colours(rig, images, masks, np.where(valid, result["distance"], 1.0))
    _report(result, rig, args.out, f"classical baseline {args.rtss_preset}")
    return 0


def _run_onnx(args, rig, images: np.ndarray, masks) -> int:
    from gijax.export.ort_predict import OnnxPredictor

    if not args.onnx:
        raise ValueError("--backend onnx needs --onnx FILE (an exported model)")
    pred = OnnxPredictor(args.onnx)
    candidates = None
    if args.candidates != "train":
        from gijax.nn.presets import ModelConfig

        config = ModelConfig(**{k: tuple(v) if isinstance(v, list) else v
                                for k, v in pred.info.config.items()})
        candidates = resolve_candidates(args.candidates, config, rig, None)[0]
    result = pred.predict(rig, images, masks, candidates)
    small = pred.info.scaled_rig(rig)
    feed_images = pred.info.feed(rig, images, masks)[0]["images"][0]
    result["colour"] = _colours(small, feed_images, None, result["distance"])
    _report(result, rig, args.out, f"ONNX model {args.onnx} (onnxruntime)")
    return 0
