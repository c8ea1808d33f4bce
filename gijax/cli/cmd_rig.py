"""``gijax rig``: show a rig (built-in or file) and list the built-in layouts."""

from __future__ import annotations

import argparse


def _show(args) -> int:
    from gijax.geometry.rig import describe_rig
    from gijax.io.rigfile import load_rig

    rig = load_rig(args.rig, frame_camera=args.frame_camera)
    print(describe_rig(rig))
    if args.plot:
        from gijax.viz.rig_plot import plot_rig

        out = plot_rig(rig, args.plot, title=f"rig {args.rig}")
        print(f"wrote {out}")
    if args.save:
        from gijax.io.rigfile import save_rig

        print(f"wrote {save_rig(rig, args.save)}")
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
        "rig", help="show a camera rig or list the built-in layouts",
        description="Inspect camera rigs: built-in layouts, gijax YAML rig files, Kalibr / "
                    "TartanCalib camchain.yaml files and basalt calibration JSON files.")
    sub = p.add_subparsers(dest="rig_command", metavar="ACTION", required=True)
    show = sub.add_parser(
        "show", help="print cameras, models, intrinsics, positions, baselines, fields of view",
        description="Print a rig's cameras (model, intrinsics, size, field of view, position, "
                    "optical axis), the pairwise baselines, the reference point and the "
                    "occluder; optionally plot a top and a side view.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    show.add_argument("rig", metavar="NAME|FILE",
                      help="a built-in name (see 'gijax rig list') or a rig/calibration file")
    show.add_argument("--plot", metavar="OUT.png", help="write a top and side view PNG")
    show.add_argument("--save", metavar="OUT.yaml",
                      help="also write the rig as a gijax YAML rig file (converts calibrations)")
    show.add_argument("--frame-camera", type=int, default=0,
                      help="for calibration files: the camera whose frame is the rig frame")
    show.set_defaults(func=_show)
    lst = sub.add_parser("list", help="list the built-in rig layouts",
                         description="List the built-in rig layouts after the paper.")
    lst.add_argument("-v", "--verbose", action="store_true",
                     help="build each rig and show its camera count and largest baseline")
    lst.set_defaults(func=_list)
