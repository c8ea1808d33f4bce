"""``gijax trt``: build TensorRT engines from exported ONNX files and run / time them."""

from __future__ import annotations

import sys

HELP = "build (gijax trt build) and run (gijax trt run) TensorRT engines"
DESCRIPTION = """\
build: parse an exported ONNX file with the installed TensorRT and write a serialized engine
(plus a .plan.json build record); prints the equivalent trtexec command for building on a
Jetson. fp16: builder flag on TensorRT <= 10; on 11.x precision comes from the ONNX file.
Strongly typed networks (precision from the file's types, no precision builder flags): the
default on 10.x for an fp16 or int8 export, always on 11.x, not available on 8.x.

run: load an engine (refusing one built by another TensorRT version), feed it one image per
camera and time it. Engines are tied to the TensorRT version and the GPU: build on the target.
"""


def register(subparsers) -> None:
    import argparse

    from gijax.cli.options import RawHelpFormatter, add_rig_option

    p = subparsers.add_parser("trt", help=HELP, description=DESCRIPTION,
                              formatter_class=RawHelpFormatter)
    sub = p.add_subparsers(dest="trt_command", metavar="build|run")
    b = sub.add_parser("build", help="ONNX -> TensorRT engine")
    b.add_argument("onnx", metavar="MODEL.onnx", help="exported file ('gijax export')")
    b.add_argument("--out", required=True, metavar="MODEL.plan",
                   help="engine file to write (a .plan.json build record beside it)")
    b.add_argument("--fp16", action="store_true", help="allow fp16 kernels (TensorRT <= 10)")
    b.add_argument("--stronglyTyped", "--strongly-typed", dest="strongly_typed",
                   action=argparse.BooleanOptionalAction, default=None,
                   help="strongly typed network: every tensor keeps the ONNX file's type, so "
                        "an fp16 / int8 export builds as written (TensorRT >= 10; default: on "
                        "for an fp16 or int8 file on 10.x, always on 11.x; not with --fp16)")
    b.add_argument("--workspace", type=int, metavar="MB", help="builder workspace limit, MiB")
    b.add_argument("--max-batch", type=int, default=1,
                   help="largest batch of a dynamic-batch file's optimisation profile")
    b.set_defaults(func=run_build)
    r = sub.add_parser("run", help="run and time an engine on one set of images")
    r.add_argument("plan", metavar="MODEL.plan", help="engine file ('gijax trt build')")
    r.add_argument("--onnx", metavar="MODEL.onnx", help="the exported file (for its metadata; "
                   "default: the file recorded at build time)")
    add_rig_option(r, required=True)
    r.add_argument("--images", required=True, nargs="+", metavar="IMAGE",
                   help="one fisheye image per camera, in the rig's camera order")
    r.add_argument("--repeats", type=int, default=20, help="timed runs of the engine")
    r.add_argument("--out", metavar="FILE.npy", help="write the distance panorama (metres)")
    r.set_defaults(func=run_engine_cmd)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _missing(exc) -> int:
    print(f"gijax trt: {exc}", file=sys.stderr)
    return 3


def run_build(args) -> int:
    from gijax.export.trt_engine import TensorRTMissing, build_engine

    try:
        info = build_engine(args.onnx, args.out, fp16=args.fp16, workspace_mb=args.workspace,
                            max_batch=args.max_batch, strongly_typed=args.strongly_typed)
    except TensorRTMissing as exc:
        return _missing(exc)
    typing = ("strongly typed: precision from the file's types" if info["strongly_typed"]
              else "weakly typed" + (", FP16 builder flag" if args.fp16 else ""))
    print(f"wrote {info['plan']} with TensorRT {info['version']} in {info['seconds']:.1f} s "
          f"({info['file_precision']} file, {typing})")
    print(f"equivalent on the device: {info['trtexec']}")
    return 0


def run_engine_cmd(args) -> int:
    import json
    from pathlib import Path

    import numpy as np

    from gijax.export.trt_engine import TensorRTMissing, load_engine, run_engine

    try:
        engine = load_engine(args.plan)
        onnx_path = args.onnx
        record = Path(args.plan + ".json")
        if onnx_path is None and record.is_file():
            onnx_path = json.loads(record.read_text()).get("onnx")
        if not onnx_path:
            raise ValueError("pass --onnx MODEL.onnx (the engine has no build record)")
        from gijax.data.images import read_images
        from gijax.export.ort_predict import ExportInfo
        from gijax.io.rigfile import load_rig

        info = ExportInfo(onnx_path)
        rig = load_rig(args.rig)
        images = read_images(args.images)
        feed, _ = info.feed(rig, images)
        outputs, times = run_engine(engine, feed, repeats=args.repeats)
    except TensorRTMissing as exc:
        return _missing(exc)
    ms = np.asarray(times[1:] or times) * 1e3
    print(f"{args.plan}: {len(times)} runs, median {np.median(ms):.2f} ms, min {ms.min():.2f} ms "
          f"(including host-device copies)")
    dist = outputs["distance"][0]
    print(f"distance {dist.shape}: median {np.median(dist):.3f} m")
    if args.out:
        from gijax.io.paths import save_npy_atomic

        save_npy_atomic(args.out, dist.astype(np.float32))
        print(f"wrote {args.out}")
    return 0
