"""``gijax export``: the whole inference graph to ONNX, validated and checked for TensorRT."""

from __future__ import annotations

HELP = "export a model (with its rig) to ONNX for onnxruntime / TensorRT"
DESCRIPTION = """\
Export raw fisheye images -> surrogate resampling -> features -> sphere sweep -> cost volume ->
U-Net -> inverse distance as one ONNX graph (jax2onnx), in eval mode.

Default: the rig and the candidates are baked in (the sampling grids become constants; fastest
engine). --rig-as-input makes intrinsics, poses, reference point and candidates graph inputs, so
a re-calibrated rig (same camera model and image size) needs no new export.

After writing, the file is checked (onnx checker), run with onnxruntime on a rendered sample and
compared with JAX (inverse distance within 1e-4 1/m; 1e-2 for --precision fp16, 0.2 for
int8), and a TensorRT compatibility report
(8.5 / 10.x / 11.x) is printed. The exit code is non-zero when a check fails.
"""


def register(subparsers) -> None:
    from gijax.cli.options import (CKPT_HELP, RawHelpFormatter, add_candidates_option,
                                   add_estimate_option, add_panorama_options, add_rig_option)
    from gijax.export.precision import DEFAULT_CALIBRATION_SCENES, PRECISIONS

    p = subparsers.add_parser("export", help=HELP, description=DESCRIPTION,
                              formatter_class=RawHelpFormatter)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--ckpt", metavar="PATH|NAME", help=CKPT_HELP)
    src.add_argument("--preset", metavar="NAME|FILE", help="model preset (or a JSON file of "
                     "ModelConfig fields) with random, UNTRAINED weights (for testing the "
                     "deployment path only)")
    add_rig_option(p, required=True)
    p.add_argument("--out", required=True, metavar="FILE", help="output .onnx file")
    p.add_argument("--opset", type=int, default=17, help="ONNX opset (default 17: TensorRT 8.5 "
                   "and later)")
    p.add_argument("--batch", type=int, default=1, help="static batch size (default 1)")
    p.add_argument("--dynamic-batch", action="store_true", help="symbolic batch axis")
    p.add_argument("--rig-as-input", action="store_true",
                   help="intrinsics, poses, reference and candidates as graph inputs")
    add_candidates_option(p, "train", "'train'", what="candidates baked in / used for "
                                                       "validation")
    add_estimate_option(p)
    p.add_argument("--seed", type=int, default=0, help="initialisation seed for --preset")
    p.add_argument("--precision", choices=PRECISIONS, default="fp32",
                   help="fp32, or fp16: feature extractor, cost-volume convolution "
                   "and U-Net in float16, sampling, softmax and regression kept float32 by "
                   "casts; int8: those convolutions quantised (QDQ, per-channel weights), the "
                   "rest float32; inputs and outputs stay float32 (docs/deploy.md)")
    p.add_argument("--calibration", type=int, default=DEFAULT_CALIBRATION_SCENES,
                   metavar="SCENES", help="int8: rendered scenes of the rig the activation "
                   "ranges are calibrated on")
    p.add_argument("--no-validate", action="store_true",
                   help="skip the onnxruntime-vs-JAX comparison on a rendered sample")
    add_panorama_options(p, "the model's output size")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from gijax.candidates.spec import model_candidates
    from gijax.export.onnx_export import export_onnx, validate_export
    from gijax.export.precision import VALIDATE_ATOL
    from gijax.export.trt_compat import check_model
    from gijax.io.paths import check_output_file
    from gijax.io.rigfile import load_rig

    check_output_file(args.out)          # a folder or a file under a file fails before the export
    rig = load_rig(args.rig)
    from gijax.store import model_or_untrained

    from gijax.cli.options import panorama_from_args
    from gijax.model import coverage_note, model_panorama, with_estimate

    model, config, train_cand, label = model_or_untrained(args.ckpt, args.preset, args.seed)
    model = with_estimate(model, args.estimate)
    config = model.config
    if not args.ckpt:
        label += " - for testing only"
    rig, pano = panorama_from_args(args, rig, model_panorama(config, "hemisphere").shape)
    note = coverage_note(config, pano)
    if note:
        print(note)
    candidates, how = model_candidates(args.candidates, rig, config, train=train_cand)
    from gijax.io.bounds import check_prediction

    # The export traces and validates the network at this panorama (times --batch samples).
    check_prediction(pano.shape, len(candidates) * max(args.batch or 1, 1))
    print(f"exporting {label}; rig {args.rig}; candidates: {how} "
          f"{np.round(candidates, 3).tolist()} m")
    result = export_onnx(model, rig, candidates, args.out, opset=args.opset, batch=args.batch,
                         dynamic_batch=args.dynamic_batch, rig_as_input=args.rig_as_input,
                         extra_metadata={"source": label, "rig": str(args.rig)}, pano=pano,
                         precision=args.precision, calibration_scenes=args.calibration)
    print(f"wrote {result.path} ({result.metadata['mode']})")
    for name, shape in result.inputs.items():
        print(f"  input  {name:13s} {shape}")
    for name, shape in result.outputs.items():
        print(f"  output {name:13s} {shape}")
    status = 0
    if not args.no_validate:
        v = validate_export(result.path, model, rig, candidates,
                            atol=VALIDATE_ATOL[args.precision])
        print(f"onnxruntime vs JAX on a rendered sample: max |d inv_distance| = "
              f"{v['max_abs_inv_distance']:.2e} 1/m, max |d entropy| = "
              f"{v['max_abs_entropy']:.2e}, valid mismatches {v['valid_mismatch']}: "
              f"{'OK' if v['ok'] else 'FAILED'}")
        status |= 0 if v["ok"] else 1
    report = check_model(result.path)
    print(report.table())
    if not report.ok():
        status |= 1
    return status
