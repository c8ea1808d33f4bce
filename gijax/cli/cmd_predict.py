"""``gijax predict``: distance panorama, colour maps and point cloud from fisheye images."""

from __future__ import annotations

import numpy as np

HELP = "estimate the distance panorama of one set of fisheye images"
DESCRIPTION = """\
Run a model on one image per camera and write, under --out: distance.npy (float32 metres, an
equirectangular panorama: 160 x 640 for the paper's hemisphere; see the panorama options),
valid.npy / valid.png (per-pixel validity: True / 255 where a distance was estimated),
inverse_distance.png (colour map with a colour bar in metres),
uncertainty.png (entropy of the learned model's candidate distribution; the classical
baseline has none and writes no such file), rgb.png (the colour panorama: each pixel the mean
colour of its predicted point over the cameras that see it), points.ply (coloured point cloud
in the rig frame) and prediction.json.

Invalid pixels (seen by too few cameras, e.g. masked out), for every method: NaN in
distance.npy (never inf), False / 0 in valid.npy / valid.png, black in the colour maps and
rgb.png, no point in points.ply; prediction.json gives valid_fraction and valid_pixels.

Image size, for every method: images of the rig's aspect ratio but another size are resized
to what the method works at (the learned model: the rig's size times its image scale; the
baseline works at the images' own size and rescales the lenses instead), with a note; images
of another aspect ratio are refused.

The model comes from a training run folder, an inference bundle, a resume pack or a bundled
model by name (--ckpt; 'gijax models' lists them), from an exported ONNX file run by onnxruntime (--backend
onnx --onnx FILE), or, for trying the pipeline, from a preset with random weights (--preset;
the outputs are then labelled UNTRAINED).
--method rtss runs the classical sphere-sweep stereo baseline instead: it has no model, so
--ckpt, --preset and --backend onnx are refused with it; --rtss-preset picks RS-E16, RS-G16,
RS-E32, RS-G32 or RS-E32-AD (the last with the paper's 1x1 absolute-difference cost). Its
default candidates are the preset's own list (RS-E32: 32 candidates even in inverse distance,
0.5-100 m; the G presets derive theirs from the rig), printed at run time.
"""


def register(subparsers) -> None:
    from gijax.cli.options import (CKPT_HELP, RawHelpFormatter, add_candidates_option,
                                   add_estimate_option, add_method_option, add_panorama_options,
                                   add_rig_option, add_rtss_preset_option)

    p = subparsers.add_parser("predict", help=HELP, description=DESCRIPTION,
                              formatter_class=RawHelpFormatter)
    add_method_option(p)
    add_rtss_preset_option(p)
    p.add_argument("--backend", choices=("jax", "onnx"), default="jax",
                   help="run the learned model in JAX (default) or an exported ONNX file with "
                        "onnxruntime (CPU, or CUDA where available)")
    p.add_argument("--onnx", metavar="FILE", help="exported model for --backend onnx")
    p.add_argument("--onnx-memory", choices=("default", "lean", "low"), default="default",
                   help="onnxruntime memory profile for --backend onnx: 'lean' skips constant "
                        "folding (about 40%% less memory, 12%% more time at paper size), 'low' "
                        "keeps the least resident memory (also no arena and glibc's mmap "
                        "threshold fixed; about 4x less memory, 1.7x the time); 'default' "
                        "keeps onnxruntime's own settings")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--ckpt", metavar="PATH|NAME", help=CKPT_HELP)
    src.add_argument("--preset", metavar="NAME|FILE", help="model preset (e.g. G16VV-cpu) or a "
                     "JSON file of ModelConfig fields, with random, UNTRAINED weights")
    add_rig_option(p, required=True)
    p.add_argument("--images", required=True, nargs="+", metavar="IMAGE",
                   help="one fisheye image per camera, in the rig's camera order")
    p.add_argument("--masks", nargs="+", metavar="MASK",
                   help="optional validity masks per camera (non-zero = valid); default: the "
                        "rig's own masks")
    add_candidates_option(p, None, "'train' for the learned model, the RTSS preset's own "
                                   "list for --method rtss")
    add_estimate_option(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--seed", type=int, default=0, help="initialisation seed for --preset")
    p.add_argument("--no-progress", action="store_true",
                   help="no elapsed-time line while the method runs (drawn only on a terminal)")
    add_panorama_options(p, "160x640 (RTSS) or the model's output size")
    p.set_defaults(func=run)


def run(args) -> int:
    from gijax.data.images import read_images
    from gijax.io.masks import read_mask, warn_if_unmasked
    from gijax.io.rigfile import load_rig
    from gijax.predict import check_prediction_folder

    # Before any work: --out must be new, empty or an earlier prediction, and hold no input.
    args.inputs = [*args.images, *(args.masks or [])]
    check_prediction_folder(args.out, args.inputs)
    args.interrupted_keeps = f"{args.out} is as it was before this command"
    rig = load_rig(args.rig)
    warn_if_unmasked(rig, args.rig, other_masks=args.masks is not None)
    if len(args.images) != rig.num_cameras:
        raise ValueError(f"rig {args.rig!r} has {rig.num_cameras} cameras but "
                         f"{len(args.images)} images were given")
    if args.masks is not None and len(args.masks) != len(args.images):
        raise ValueError(f"{len(args.masks)} masks given for {len(args.images)} images")
    images = read_images(args.images)
    masks = None
    if args.masks is not None:
        masks = np.stack([read_mask(p) for p in args.masks])
    if args.method == "rtss":
        # The baseline has no weights: a model named with it would be silently unused.
        given = [opt for opt, on in (("--ckpt", args.ckpt), ("--preset", args.preset),
                                     ("--backend onnx", args.backend == "onnx"),
                                     ("--estimate", args.estimate)) if on]
        if given:
            raise ValueError(f"--method rtss runs the classical baseline, which uses no model; "
                             f"drop {' and '.join(given)} (or use --method learned)")
        return _run_rtss(args, rig, images, masks)
    if args.candidates is None:
        args.candidates = "train"
    if args.backend == "onnx":
        if args.estimate:
            raise ValueError("--backend onnx runs the estimate the ONNX file was exported with; "
                             "drop --estimate (or export with 'gijax export --estimate')")
        return _run_onnx(args, rig, images, masks)
    if not (args.ckpt or args.preset):
        raise ValueError("the learned method needs --ckpt RUN (or --preset NAME for an untrained "
                         "model)")
    return _run_learned(args, rig, images, masks)


def _run_learned(args, rig, images: np.ndarray, masks) -> int:
    from gijax.candidates.spec import model_candidates
    from gijax.cli.options import panorama_from_args
    from gijax.io.bounds import check_prediction
    from gijax.model import model_panorama, with_estimate
    from gijax.predict import LearnedPredictor
    from gijax.store import model_or_untrained

    model, config, train_cand, label = model_or_untrained(args.ckpt, args.preset, args.seed)
    model = with_estimate(model, args.estimate)
    config = model.config
    hemi = model_panorama(config, "hemisphere").shape
    rig, pano = panorama_from_args(args, rig, hemi)
    candidates, how = model_candidates(args.candidates, rig, config, train=train_cand)
    check_prediction(pano.shape, len(candidates))
    from gijax.store.envelope import warn_if_outside_training

    warn_if_outside_training(rig, args.ckpt, config.name)
    from gijax.cli.waiting import working

    with working(f"{config.name} network (compiles on the first call)",
                 enabled=not args.no_progress):
        result = LearnedPredictor(model, candidates, pano).predict(rig, images, masks, log=print)
    title = f"{label}; candidates: {how}"
    _report(result, rig, args, title)
    return 0


def _report(result: dict, rig, args, title: str) -> None:
    from gijax.predict import mark_invalid, write_prediction

    paths = write_prediction(result, rig, args.out, title=title, inputs=args.inputs)
    print(title)
    # The files' convention: only valid pixels with a finite distance count.
    marked = mark_invalid(result)
    valid = marked["valid"]
    median = (f"median {np.median(marked['distance'][valid]):.3f} m over valid pixels"
              if valid.any() else "no valid pixel")
    print(f"distance {result['distance'].shape}: {median}, valid {valid.mean() * 100:.1f} %")
    for kind, path in paths.items():
        print(f"  {kind:22s} {path}")


def _run_rtss(args, rig, images: np.ndarray, masks) -> int:
    """The classical baseline at the images' own size; the panorama by default the paper's
    angular resolution (160 x 640 for the hemisphere)."""
    from gijax.baseline.rtss import choose_candidates, get_rtss_preset
    from gijax.cli.options import panorama_from_args
    from gijax.data.images import fit_images
    from gijax.io.bounds import check_prediction
    from gijax.predict import RtssPredictor

    config = get_rtss_preset(args.rtss_preset)
    rig, pano = panorama_from_args(args, rig, (160, 640))
    rig, images, masks = fit_images(rig, images, masks, None, log=print)
    candidates, how = choose_candidates(args.candidates, rig, config)
    check_prediction(pano.shape, len(candidates))
    print(f"candidates: {how}; {len(candidates)} from {float(candidates[0]):.3f} to "
          f"{float(candidates[-1]):.3f} m")
    from gijax.cli.waiting import working

    with working(f"{args.rtss_preset} sphere sweep (compiles on the first call)",
                 enabled=not args.no_progress):
        result = RtssPredictor(args.rtss_preset, candidates, pano).predict(rig, images, masks)
    _report(result, rig, args, f"classical baseline {args.rtss_preset}; candidates: {how}")
    return 0


def _run_onnx(args, rig, images: np.ndarray, masks) -> int:
    from gijax.candidates.spec import model_candidates
    from gijax.export.ort_predict import OnnxPredictor
    from gijax.predict import point_colours

    if not args.onnx:
        raise ValueError("--backend onnx needs --onnx FILE (an exported model)")
    given = [o for o, on in (("--panorama", args.panorama != "auto"), ("--up", args.up),
                             ("--panorama-size", args.panorama_size)) if on]
    if given:
        raise ValueError(f"an ONNX file's panorama is fixed when it is exported; drop "
                         f"{', '.join(given)} (or export with 'gijax export {given[0]} ...')")
    pred = OnnxPredictor(args.onnx, memory=args.onnx_memory)
    candidates = None
    if args.candidates != "train":  # the exported list is baked in unless another is asked for
        from gijax.store.configs import model_config_from_dict

        config = model_config_from_dict(pred.info.config)
        candidates = model_candidates(args.candidates, rig, config)[0]
    rig = pred.info.oriented_rig(rig)
    from gijax.cli.waiting import working

    with working("onnxruntime", enabled=not args.no_progress):
        result = pred.predict(rig, images, masks, candidates, log=print)
    small = pred.info.scaled_rig(rig)
    feed_images = pred.info.feed(rig, images, masks)[0]["images"][0]
    result = result.replace(colour=point_colours(small, feed_images, None, result.distance,
                                                 result.panorama))
    _report(result, rig, args, f"ONNX model {args.onnx} (onnxruntime)")
    return 0
