"""``gijax demo``: the first thing to run after installing."""

from __future__ import annotations


def _run(args) -> int:
    from gijax.demo import run_demo

    run_demo(args.out, seed=args.seed, model=args.model, baseline=args.baseline,
             progress=not args.quiet)
    return 0


def register(sub) -> None:
    from gijax.demo import DEFAULT_MODEL

    p = sub.add_parser(
        "demo",
        help="render fresh scenes, run the bundled model and the classical baseline, compare",
        description=(
            "Renders a fresh scene with exact labels on the training rig (paper-train, 3 cameras "
            "0.31 m apart) and on a new rig (paper-test3, 4 cameras 1 m apart), runs the bundled "
            "G16VV-cpu model with its training candidates, with the paper's list recomputed "
            "for the rig (closed-form GI at the rig's camera spacing) and with gijax's "
            "rig-aware GI list, and the classical RTSS baseline, prints MAE / RMSE / SSIM "
            "(inverse distance, 1/m, the paper's definitions) and time, and writes demo.png (inputs, ground truth, predictions, "
            "error maps), points.ply (coloured point cloud) and demo.json."),
    )
    p.add_argument("--out", default="gijax-demo", help="output folder (default: gijax-demo)")
    p.add_argument("--seed", type=int, default=None,
                   help="scene seed (default: a fresh random scene each run; the seed is printed)")
    p.add_argument("--ckpt", "--model", dest="model", default=DEFAULT_MODEL,
                   metavar="PATH|NAME",
                   help=f"the model: a training run folder, an inference bundle or the name of "
                        f"a bundled model (see 'gijax models'; default {DEFAULT_MODEL})")
    p.add_argument("--baseline", default="RS-E32",
                   help="classical baseline configuration: RS-E16, RS-G16, RS-E32, RS-G32, RS-E32-AD")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_run)
