"""``gijax render``: generate a procedural multi-fisheye dataset in the dataset format
(:func:`gijax.data.rendered.render_dataset`; the folder is locked while it is written)."""

from __future__ import annotations

import argparse

from gijax.cli.options import add_panorama_options
from gijax.geometry.rig import Rig
from gijax.io.rigfile import load_rig

STYLES = ("mixed", "indoor", "outdoor")


def _pair(text: str, what: str) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what} must look like 640x160; found {text!r}") from None
    if a < 1 or b < 1:
        raise argparse.ArgumentTypeError(f"{what} must be positive; found {text!r}")
    return a, b


def _scale_for(rig: Rig, args) -> float:
    """The image scale factor from --scale or --size (which must keep every camera's aspect)."""
    if args.size is None:
        return float(args.scale)
    w, h = args.size
    factors = set()
    for name, cam in zip(rig.names, rig.cameras):
        fw, fh = w / cam.width, h / cam.height
        if abs(fw - fh) > 1e-9:
            raise ValueError(f"--size {w}x{h} changes the aspect of camera {name!r} "
                             f"({cam.width}x{cam.height}); use --scale")
        factors.add(fw)
    if len(factors) != 1:
        raise ValueError(f"--size {w}x{h} needs every camera to have the same size; use --scale")
    return factors.pop()


def run(args) -> int:
    from gijax.data.rendered import render_dataset

    if args.samples < 1:
        raise ValueError(f"--samples must be >= 1; found {args.samples}")
    from gijax.cli.options import panorama_from_args

    base, pano = panorama_from_args(args, load_rig(args.rig), (160, 640), size=args.pano)
    if args.lens != "keep":
        from gijax.data.lens_draw import LensDraw, lens_variant_rig
        import math

        base, model = lens_variant_rig(args.lens_seed, base, args.lens,
                                       LensDraw(fov_deg=tuple(args.fov_range)))
        fovs = ", ".join(f"{math.degrees(float(c.fov)):.0f}" for c in base.cameras)
        print(f"lenses drawn (seed {args.lens_seed}): {model}, fields of view {fovs} deg")
    h, w = pano.shape
    args.interrupted_keeps = (f"{args.out} keeps the samples written so far; the same "
                              f"command continues from them")
    rig = render_dataset(base, args.out, args.samples, seed=args.seed,
                         image_scale=_scale_for(base, args), pano=pano, style=args.style,
                         trajectory_size=args.trajectory_size, durable=args.durable, log=print)
    print(f"{args.out}: {args.samples} samples ({rig.num_cameras} cameras "
          f"{rig.cameras[0].width}x{rig.cameras[0].height}, panorama {w}x{h})")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "render",
        help="render a procedural multi-fisheye dataset (RGB, distance, masks, panorama labels)",
        description=(
            "Render N procedural samples for a rig and store them in the gijax dataset format "
            "(docs/data.md): per camera an RGB fisheye, its distance (float32 in a 4-channel "
            "PNG) and validity mask, plus the ground-truth panorama distance. Writing is "
            "crash-safe; re-running the same command resumes after the last complete sample "
            "and yields the same data as an uninterrupted run. The manifest records the "
            "requested count before any sample, so readers know an interrupted dataset is "
            "incomplete ('gijax data check' reports it; train and eval refuse it without "
            "--allow-partial); re-running with --samples equal to what it holds accepts it as "
            "it is. One writer at a time: a second command writing the same folder fails "
            "naming the first one's PID."),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--rig", required=True,
                   help="built-in rig name (paper-train, paper-test1, paper-test2, paper-test3) "
                        "or a rig file (gijax YAML, Kalibr camchain.yaml, basalt JSON)")
    p.add_argument("--samples", type=int, required=True, help="total number of samples")
    p.add_argument("--out", required=True, help="dataset folder (created, or resumed)")
    p.add_argument("--seed", type=int, default=0, help="dataset seed; sample i uses a seed "
                                                       "derived from (seed, i)")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--scale", type=float, default=1.0,
                      help="scale every camera image by this factor (0.25 for the -cpu presets)")
    size.add_argument("--size", type=lambda s: _pair(s, "--size"), default=None,
                      metavar="WxH", help="every camera's image size (keeps the aspect)")
    p.add_argument("--pano", type=lambda s: tuple(reversed(_pair(s, "--pano"))),
                   default=None, metavar="WxH",
                   help="ground-truth panorama size, width x height (default 640x160 for the "
                        "hemisphere, the paper's, and 640x320 for the sphere; 128x32 matches "
                        "the -cpu presets' output)")
    add_panorama_options(p, "640x160", size=False)
    p.add_argument("--style", choices=STYLES, default="mixed",
                   help="scene style; mixed picks indoor or outdoor per sample")
    p.add_argument("--lens", default="keep", choices=["keep", "random", "equidistant", "kb", "ds"],
                   help="keep the rig's lenses, or render through drawn ones: one model for the "
                        "rig ('random' draws it), per camera a field of view in --fov-range, an "
                        "image circle of 85-100 %% of the half image and a monotonic shape "
                        "(docs/data.md, Lens draws); the drawn rig is the dataset's rig")
    p.add_argument("--lens-seed", type=int, default=0, help="seed of the lens draw")
    p.add_argument("--fov-range", type=float, nargs=2, default=[180.0, 240.0],
                   metavar=("LOW", "HIGH"), help="field of view of drawn lenses, degrees")
    p.add_argument("--trajectory-size", type=int, default=1000,
                   help="samples per trajectory folder")
    p.add_argument("--durable", action="store_true",
                   help="fsync every file before committing it (survives power loss)")
    p.set_defaults(func=run)
