"""``gijax demo``: the first thing to run after installing."""

from __future__ import annotations


def _run(args) -> int:
    from gijax.demo import run_demo

    run_demo(args.out, seed=args.seed, model=args.model, baseline=args.baseline,
             progress=not args.quiet, scenes=args.scenes)
    return 0


def register(sub) -> None:
    from gijax.baseline.rtss import RTSS_PRESETS
    from gijax.demo import DEFAULT_MODEL, DEFAULT_SCENES, MAX_SCENES

    p = sub.add_parser(
        "demo",
        help="render fresh scenes, run the bundled model and the classical baseline, compare",
        description=(
            "Renders fresh scenes with exact labels on the training rig (paper-train, 3 cameras "
            "0.31 m apart) and on a new rig (paper-test3, 4 cameras 1 m apart), runs the default "
            f"bundled model ({DEFAULT_MODEL}; --ckpt picks another) with its training "
            "candidates, with the paper's list recomputed for the rig (closed-form GI at the "
            "rig's camera spacing) and with gijax's rig-aware GI list, and the classical RTSS "
            "baseline on each scene, prints MAE / RMSE / SSIM (inverse distance, 1/m, the "
            "paper's definitions; the mean over the scenes and the per-scene range), time and a "
            "verdict per rig, and writes demo.png (inputs, ground truth, predictions, error maps "
            "of each rig's first scene), points.ply (coloured point cloud) and demo.json (every "
            "scene's numbers)."),
    )
    p.add_argument("--out", default="gijax-demo", help="output folder (default: gijax-demo)")
    p.add_argument("--seed", type=int, default=None,
                   help="scene seed (default: fresh random scenes each run; the seed is printed)")
    p.add_argument("--scenes", type=int, default=DEFAULT_SCENES,
                   help=f"scenes per rig, 1-{MAX_SCENES} (default {DEFAULT_SCENES}); every "
                        f"method is scored on each")
    p.add_argument("--ckpt", "--model", dest="model", default=DEFAULT_MODEL,
                   metavar="PATH|NAME",
                   help=f"the model: a training run folder, an inference bundle, a resume pack "
                        f"or the name of a bundled model (see 'gijax models'; default "
                        f"{DEFAULT_MODEL})")
    p.add_argument("--baseline", default="RS-E32",
                   help=f"classical baseline configuration: {', '.join(sorted(RTSS_PRESETS))} "
                        f"(default RS-E32)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_run)
