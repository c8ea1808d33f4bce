"""``gijax rig``: show a rig (built-in or file), import a calibration with its masks, and list
the built-in layouts."""

from __future__ import annotations

import argparse

from gijax.cli.options import add_panorama_options


def _oriented(args, rig):
    """The rig with its panorama frame chosen by --panorama / --up (stored by --save / --out),
    reported on one line."""
    from gijax.cli.options import panorama_from_args

    return panorama_from_args(args, rig, (160, 640))[0]


def _show(args) -> int:
    from gijax.geometry.rig import describe_rig
    from gijax.io.masks import import_rig, unmasked_message

    if args.save:
        from gijax.io.paths import check_output_file

        check_output_file(args.save, "--save")
    rig = import_rig(args.rig, masks=args.masks, frame_camera=args.frame_camera)
    rig = _oriented(args, rig)
    print(describe_rig(rig))
    note = unmasked_message(rig, args.rig)
    if note:
        print(f"note: {note}")
    if args.plot:
        from gijax.viz.rig_plot import plot_rig

        out = plot_rig(rig, args.plot, title=f"rig {args.rig}")
        print(f"wrote {out}")
    if args.save:
        from gijax.io.rigfile import save_rig

        print(f"wrote {save_rig(rig, args.save)}")
    return 0


def _import(args) -> int:
    from gijax.geometry.rig import describe_rig
    from gijax.io.masks import import_rig, unmasked_message
    from gijax.io.paths import check_output_file
    from gijax.io.rigfile import mask_file_name, save_rig

    check_output_file(args.out)
    rig = import_rig(args.calibration, masks=args.masks, names=args.names,
                     frame_camera=args.frame_camera)
    rig = _oriented(args, rig)
    print(f"imported {args.calibration}")
    print(describe_rig(rig))
    out = save_rig(rig, args.out)
    if args.masks:
        print("masks (copied beside the rig file, nonzero = valid):")
        for name, src in zip(rig.names, args.masks):
            print(f"  {name}: {src} -> {out.parent / mask_file_name(out, name)}")
    note = unmasked_message(rig, args.calibration)
    if note:
        print(f"note: {note}")
    print(f"wrote {out}")
    return 0


def _list(args) -> int:
    from gijax.geometry.layouts import BUILTIN_LAYOUTS, builtin_rig
    from gijax.geometry.rig import pairwise_baselines

    for name in sorted(BUILTIN_LAYOUTS):
        rig = builtin_rig(name) if args.verbose else None
        extra = ""
        if rig is not None:
            b = pairwise_baselines(rig)
            extra = f"  {rig.num_cameras} cameras, max baseline {b.max():.3f} m"
        doc = BUILTIN_LAYOUTS[name].__doc__ or ""
        print(f"{name}{extra}{('  ' + doc.strip()) if doc else ''}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "rig", help="show a camera rig, import a calibration with masks, or list the built-in "
                    "layouts",
        description="Inspect camera rigs (built-in layouts, gijax YAML rig files, Kalibr / "
                    "TartanCalib camchain.yaml files and basalt calibration JSON files) and "
                    "import calibrations with their per-camera masks.")
    sub = p.add_subparsers(dest="rig_command", metavar="ACTION", required=True)
    show = sub.add_parser(
        "show", help="print cameras, models, intrinsics, positions, baselines, fields of view",
        description="Print a rig's cameras (model, intrinsics, size, position, optical axis, "
                    "field of view: the widest angle the image sees, the lens model's own "
                    "limit and the cone the image holds completely), the pairwise baselines, "
                    "the reference point and the occluder, and a note when cameras of a rig "
                    "file have no mask; optionally plot a top and a side view.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    show.add_argument("rig", metavar="NAME|FILE",
                      help="a built-in name (see 'gijax rig list') or a rig/calibration file")
    show.add_argument("--plot", metavar="OUT.png", help="write a top and side view PNG")
    show.add_argument("--save", metavar="OUT.yaml",
                      help="also write the rig as a gijax YAML rig file (converts calibrations)")
    show.add_argument("--masks", nargs="+", metavar="MASK.png",
                      help="per-camera rig masks, in camera order, each the size of its "
                           "camera's image (nonzero = sees the world); shown and saved with "
                           "--save")
    show.add_argument("--frame-camera", type=int, default=0,
                      help="for calibration files: the camera whose frame is the rig frame")
    add_panorama_options(show, "160x640", size=False)
    show.set_defaults(func=_show)
    imp = sub.add_parser(
        "import", help="turn a calibration and per-camera masks into a gijax rig file",
        description="Read a calibration (Kalibr / TartanCalib camchain.yaml, basalt "
                    "calibration JSON, or a gijax rig file), attach one rig mask per camera "
                    "(a PNG the size of that camera's image, nonzero = sees the world, zero = "
                    "the rig's own body), and write a gijax YAML rig file with the masks "
                    "beside it. Prints what was imported and the path written.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    imp.add_argument("calibration", metavar="CALIB",
                     help="camchain.yaml, basalt calibration JSON or gijax rig file")
    imp.add_argument("--masks", nargs="+", metavar="MASK.png",
                     help="one mask PNG per camera, in camera order")
    imp.add_argument("--names", nargs="+", metavar="NAME",
                     help="camera names, in camera order (default: cam0, cam1, ... or the "
                          "file's own)")
    imp.add_argument("--out", required=True, metavar="RIG.yaml", help="rig file to write")
    imp.add_argument("--frame-camera", type=int, default=0,
                     help="the camera whose frame is the rig frame")
    add_panorama_options(imp, "160x640", size=False)
    imp.set_defaults(func=_import)
    lst = sub.add_parser("list", help="list the built-in rig layouts",
                         description="List the built-in rig layouts after the paper.")
    lst.add_argument("-v", "--verbose", action="store_true",
                     help="build each rig and show its camera count and largest baseline")
    lst.set_defaults(func=_list)
