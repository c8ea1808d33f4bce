"""``gijax rig``: show a rig (built-in or file), import a calibration with its masks, list the
built-in layouts, and refine a calibration from unlabeled images."""

from __future__ import annotations


from gijax.cli.options import HelpFormatter, add_panorama_options, rig_help


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


def _refine(args) -> int:
    import json

    import numpy as np

    from gijax.calibrate.constraint import (constraint_lines, pose_constraint,
                                            weak_constraint_lines)
    from gijax.calibrate.frames import read_frames
    from gijax.calibrate.refine import (GAUGE, RefineConfig, refine_panorama, refine_rig,
                                        transfer_refinement)
    from gijax.calibrate.refine import implausible_moves, refine_scale, round_move_line
    from gijax.data.images import fit_images
    from gijax.io.masks import import_rig
    from gijax.io.paths import check_output_file, write_text_atomic
    from gijax.io.rigfile import save_rig

    check_output_file(args.out)
    for option in ("plot", "json"):
        if getattr(args, option):
            check_output_file(getattr(args, option), f"--{option}")
    if args.scale is not None and not 0 < args.scale <= 1:
        raise ValueError(f"--scale must be in (0, 1]; found {args.scale}")
    if args.rounds < 1:
        raise ValueError(f"--rounds must be at least 1; found {args.rounds}")
    rig = import_rig(args.rig)
    images, masks, labels = read_frames(args.frames, rig, args.max_frames)
    cam = rig.cameras[0]
    scale = refine_scale(cam.width) if args.scale is None else args.scale
    size = (max(8, round(cam.height * scale)), max(8, round(cam.width * scale)))
    fitted = [fit_images(rig, im, m, size) for im, m in zip(images, masks)]
    work = fitted[0][0]
    work_images = np.stack([f[1] for f in fitted])
    work_masks = np.stack([f[2] for f in fitted])
    rounds = f" in each of {args.rounds} rounds" if args.rounds > 1 else ""
    print(f"refining {rig.num_cameras} cameras from {len(labels)} frame(s) at "
          f"{size[0]}x{size[1]} px ({args.steps} steps{rounds}"
          f"{', intrinsics too' if args.intrinsics else ''})")
    print(f"gauge: {GAUGE}")
    if args.flatten is not None and not 0 <= args.flatten < 0.5:
        raise ValueError(f"--flatten must be in [0, 0.5); found {args.flatten}")
    if args.occlusion is not None and not 0 <= args.occlusion < 1:
        raise ValueError(f"--occlusion must be in [0, 1); found {args.occlusion}")
    config = RefineConfig(steps=args.steps, intrinsics=args.intrinsics, rounds=args.rounds,
                          **({} if args.smoothness is None else {"smoothness": args.smoothness}),
                          **({} if args.flatten is None else {"flatten": args.flatten}),
                          **({} if args.occlusion is None else {"occlusion": args.occlusion}))
    start = None
    if args.start_distance is not None:
        if not args.start_distance > 0:
            raise ValueError(f"--start-distance must be > 0 metres; found {args.start_distance}")
        start = np.full((len(labels), *refine_panorama(work, config).shape),
                        1.0 / args.start_distance)
    result = refine_rig(work, work_images, work_masks, config, labels=labels, initial_inv=start,
                        progress=not args.no_progress)
    refined = transfer_refinement(rig, work, result.rig)
    out = save_rig(refined, args.out)
    moved = result.moved
    print("camera moves (refined vs given):")
    for i, name in enumerate(rig.names):
        print(f"  {name}: {moved['rotation_deg'][i]:.4f} deg, {moved['translation_mm'][i]:.2f} mm")
    print(f"photometric loss: {result.loss_before:.5f} before, {result.loss_after:.5f} after")
    for k, step_move in enumerate(result.round_moves, start=2):
        print(round_move_line(k, step_move))
    constraint = pose_constraint(result.rig, work_images, work_masks, result.inv_distance,
                                 config)
    print("how well the frames fix each pose (predicted deviation at the refined calibration, "
          "a lower bound; camera 0 is the gauge):")
    for line in constraint_lines(constraint):
        print(line)
    for line in implausible_moves(rig, moved) + weak_constraint_lines(constraint, work):
        print(f"warning: {line}")
    print(f"wrote {out}")
    if args.plot:
        from gijax.calibrate.plots import plot_loss_curve

        print(f"wrote {plot_loss_curve(result.history, args.plot, f'refining {args.rig}')}")
    if args.json:
        doc = {"rig": str(args.rig), "out": str(out), "frames": labels, "steps": args.steps,
               "rounds": args.rounds,
               "round_moves": [{"rotation_deg": m["rotation_deg"],
                                "translation_mm": m["translation_mm"]}
                               for m in result.round_moves],
               "scale": scale, "intrinsics": bool(args.intrinsics), "gauge": GAUGE,
               "flatten": config.flatten, "occlusion": config.occlusion,
               "smoothness": config.smoothness,
               "loss_before": result.loss_before, "loss_after": result.loss_after,
               "cameras": [{"name": n, "rotation_deg": moved["rotation_deg"][i],
                            "translation_mm": moved["translation_mm"][i]}
                           for i, n in enumerate(rig.names)],
               "constraint": constraint, "history": result.history}
        print(f"wrote {write_text_atomic(args.json, json.dumps(doc, indent=2))}")
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
        formatter_class=HelpFormatter)
    show.add_argument("rig", metavar="NAME|FILE", help=rig_help())
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
        formatter_class=HelpFormatter)
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
    ref = sub.add_parser(
        "refine", help="refine a rig's camera poses (and intrinsics) from unlabeled images",
        description="Refine the camera-to-rig poses of a rig (and, with --intrinsics, the "
                    "focal lengths and principal points) by making the cameras agree "
                    "photometrically on a few unlabeled frames: per frame a panorama distance "
                    "map around the reference point, started from the classical baseline, is "
                    "optimised jointly with the poses. Camera 0's pose and the distance "
                    "between cameras 0 and 1 are held (images cannot tell where the rig is or "
                    "how large it is). A frame is a folder of one image per camera named "
                    "after the rig's cameras (cam0.png, cam1.png, ...; an optional "
                    "<name>_mask.png beside each), or a gijax dataset folder (one frame per "
                    "sample). Prints how far each camera moved, the photometric loss "
                    "before and after, and how well the frames fix each pose: the predicted "
                    "deviation of its rotation and of its translation along the least "
                    "constrained direction, from the objective's curvature with the distance "
                    "maps re-fitted (a warning names a camera the frames leave loose).",
        formatter_class=HelpFormatter)
    ref.add_argument("rig", metavar="NAME|FILE", help="the rig to refine: " + rig_help())
    ref.add_argument("--frames", nargs="+", required=True, metavar="DIR",
                     help="frame folders (one image per camera, named after the rig's "
                          "cameras) or gijax dataset folders")
    ref.add_argument("--out", required=True, metavar="RIG2.yaml",
                     help="refined rig file to write (masks beside it)")
    ref.add_argument("--intrinsics", action="store_true",
                     help="also refine every camera's focal length (fx and fy by one factor) "
                          "and principal point")
    ref.add_argument("--steps", type=int, default=300,
                     help="Adam steps, split over three blur levels (coarse to fine)")
    ref.add_argument("--rounds", type=int, default=1,
                     help="run the whole schedule this many times, each round after the first "
                          "restarting from the classical baseline's distances matched at the "
                          "calibration the previous round reached (the first round's were "
                          "matched at the given, wrong one; costs a round's time each)")
    ref.add_argument("--scale", type=float, default=None,
                     help="working image scale: images and lenses are resized by this factor "
                          "before refining (the refined poses hold at any size); default: the "
                          "factor that makes the images 256 px wide, never enlarging "
                          "(0.25 for 1024 px cameras, 1 for 256 px ones)")
    ref.add_argument("--smoothness", type=float, default=None,
                     help="weight of the edge-aware smoothness of the distance maps (default "
                          "0.02, RefineConfig's; lighter lets the distances follow the scene "
                          "and the poses settle nearer the truth where the frames are sharp: "
                          "on renders of 1 m rigs at 512 px, --scale 0.5 --smoothness 0.002 "
                          "recovered poses to about 0.1 deg, see experiments/RESULTS.md)")
    ref.add_argument("--flatten", type=float, default=None, metavar="FRACTION",
                     help="divide each pixel's brightness by its neighbourhood's mean, the "
                          "neighbourhood a Gaussian of this fraction of the image width "
                          "(default 0.05, RefineConfig's; 0: one gain per camera and channel "
                          "only). Removes vignetting, which differs per lens and otherwise "
                          "pulls the poses: on renders whose lenses darken up to 35 %% at the "
                          "rim, a refinement started at the true poses drifted 6 mm without "
                          "it and under 1 mm with it")
    ref.add_argument("--occlusion", type=float, default=None, metavar="MARGIN",
                     help="compare a camera's colour at a panorama point only where no nearer "
                          "point of the frame's distance map hides that point from the camera, "
                          "MARGIN being how much farther (relative, in inverse distance) than "
                          "the nearest point in its direction it may lie and still count as "
                          "seen (default 0.05, RefineConfig's; 0: every point counts as seen). "
                          "Cameras far apart see different stretches of a wall behind a post: "
                          "on renders of a 1 m rig, a refinement started at the true poses "
                          "drifted up to 4.6 mm without the test and 2.7 mm with it")
    ref.add_argument("--start-distance", type=float, metavar="METRES",
                     help="start every panorama ray at this distance instead of at the classical "
                          "baseline's estimate (faster; for scenes the baseline handles badly)")
    ref.add_argument("--max-frames", type=int, default=8,
                     help="use at most this many frames (the first ones)")
    ref.add_argument("--plot", metavar="LOSS.png", help="write the loss curve as a PNG")
    ref.add_argument("--json", metavar="REPORT.json",
                     help="write the report (per camera moves, losses, predicted deviations, "
                          "loss history) as JSON")
    ref.add_argument("--no-progress", action="store_true", help="no progress bar")
    ref.set_defaults(func=_refine)
