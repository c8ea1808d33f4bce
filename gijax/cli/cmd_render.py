"""``gijax render``: generate a procedural multi-fisheye dataset in the dataset format
(:func:`gijax.data.rendered.render_dataset`; the folder is locked while it is written)."""

from __future__ import annotations

from gijax.cli.options import (HelpFormatter, add_panorama_options, add_rig_option, hw_type,
                               wh_type)
from gijax.geometry.rig import Rig
from gijax.io.rigfile import load_rig

STYLES = ("mixed", "indoor", "outdoor")


def _size_option(args) -> str:
    return "--image-size" if args.image_size is not None else "--size"


def _scale_for(rig: Rig, args) -> float:
    """The image scale factor from --scale or --image-size / --size (which must keep every
    camera's aspect)."""
    size = args.image_size if args.image_size is not None else args.size
    if size is None:
        from gijax.io.bounds import check_scale

        return check_scale("--scale", args.scale)
    h, w = size
    given = f"{_size_option(args)} " + (f"{h}x{w}" if args.image_size is not None else f"{w}x{h}")
    factors = set()
    for name, cam in zip(rig.names, rig.cameras):
        fw, fh = w / cam.width, h / cam.height
        if abs(fw - fh) > 1e-9:
            swapped = abs(h / cam.width - w / cam.height) < 1e-9
            hint = (f"; {_size_option(args)} reads "
                    f"{'HxW (rows x columns)' if args.image_size is not None else 'WxH'}, "
                    f"the other order keeps it" if swapped else "; use --scale")
            raise ValueError(f"{given} changes the aspect of camera {name!r} "
                             f"({cam.height}x{cam.width} HxW){hint}")
        factors.add(fw)
    if len(factors) != 1:
        raise ValueError(f"{given} needs every camera to have the same size; use --scale")
    return factors.pop()


def run(args) -> int:
    from gijax.data.rendered import render_dataset

    if args.samples < 1:
        raise ValueError(f"--samples must be >= 1; found {args.samples}")
    from gijax.cli.options import panorama_from_args

    if args.pano is not None and args.panorama_size is not None:
        raise ValueError("--pano (WxH) and --panorama-size (HxW) give the same size; drop --pano")
    base, pano = panorama_from_args(args, load_rig(args.rig), (160, 640), size=args.pano)
    if args.lens != "keep":
        from gijax.data.lens_draw import LensDraw, lens_variant_rig
        import math

        base, model = lens_variant_rig(args.lens_seed, base, args.lens,
                                       LensDraw(fov_deg=tuple(args.fov_range)))
        fovs = ", ".join(f"{math.degrees(float(c.fov)):.0f}" for c in base.cameras)
        print(f"lenses drawn (seed {args.lens_seed}): {model}, fields of view {fovs} deg")
    h, w = pano.shape
    scale = _scale_for(base, args)
    from gijax.geometry.cameras import scale_camera
    from gijax.io.bounds import check_render

    # Before the output folder exists: a size that cannot be rendered leaves nothing behind.
    scaled = [scale_camera(cam, scale) for cam in base.cameras]
    check_render([(name, c.width, c.height) for name, c in zip(base.names, scaled)], (w, h))
    args.interrupted_keeps = (f"{args.out} keeps the samples written so far; the same "
                              f"command continues from them")
    rig = render_dataset(base, args.out, args.samples, seed=args.seed,
                         image_scale=scale, pano=pano, style=args.style,
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
            "incomplete ('gijax data check' reports it; train and eval refuse it unless told "
            "otherwise, 'gijax train --allow-partial'); re-running with --samples equal to "
            "what it holds accepts it as it is. One writer at a time: a second command writing the same folder fails "
            "naming the first one's PID."),
        formatter_class=HelpFormatter)
    add_rig_option(p, required=True)
    p.add_argument("--samples", type=int, required=True, help="total number of samples")
    p.add_argument("--out", required=True, help="dataset folder (created, or resumed)")
    p.add_argument("--seed", type=int, default=0, help="dataset seed; sample i uses a seed "
                                                       "derived from (seed, i)")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--scale", type=float, default=1.0,
                      help="scale every camera image by this factor (0.25 for the -cpu presets)")
    size.add_argument("--image-size", type=hw_type("--image-size"), default=None,
                      metavar="HxW", help="every camera's image size, rows x columns (must keep "
                                          "the aspect)")
    size.add_argument("--size", type=wh_type("--size", "--image-size"), default=None,
                      metavar="WxH", help="older form of --image-size, width x height")
    add_panorama_options(p, "160x640")
    p.add_argument("--pano", type=wh_type("--pano", "--panorama-size"), default=None,
                   metavar="WxH", help="older form of --panorama-size, width x height")
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
