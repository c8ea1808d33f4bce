"""``gijax adapt``: fine-tune a trained network on unlabeled frames of a rig
(:func:`gijax.train.rig_adaptation.adapt_network`)."""

from __future__ import annotations

import shlex

HELP = "fine-tune a trained network on unlabeled frames of your rig (no ground truth)"
DESCRIPTION = """\
Adapt a trained model (--ckpt) to a rig from a few unlabeled frames of it: the network's
weights are fine-tuned by a label-free objective, and the result is written as an inference
bundle (--out) that every --ckpt accepts.

Objective, each term with its weight (0 leaves it out):
  --photometric  each predicted panorama point is projected into every camera and the
                 cameras' colours there are compared (masks respected; a camera that a nearer
                 predicted point hides the point from is left out, see --occlusion; each
                 camera's colours first scaled to the cameras' common mean): the right
                 distance makes them agree;
  --smoothness   edge-aware smoothness of the predicted inverse distance (divided by its
                 mean): differences between neighbouring pixels cost exp(-EDGE |colour
                 difference|) of the reference panorama (the cameras' mean colour at the
                 predicted points), so depth may jump at colour edges;
  --teacher      smooth L1 to the classical baseline's inverse distance (--teacher-preset)
                 where it is trusted: it gave an estimate and the cameras' colours agree at
                 its distance (dispersion <= --teacher-max-dispersion).

Frames (--frames): folders of one image per camera named after the rig's cameras (cam0.png,
cam1.png, ...; an optional <name>_mask.png beside each), as 'gijax rig refine --frames' reads
them, and/or gijax dataset folders (one frame per sample; made by 'gijax render' or 'gijax
data'). Labels a dataset holds are never used for the objective. Images are resized to the
model's image size as 'gijax predict' resizes them.

--val DATASET scores the model against that dataset's labels before adapting, every
--val-every steps and at the end: a validation score only, logged as split 'val' in
metrics.jsonl and printed, never part of the objective.

The run folder OUT.adapt/ beside the bundle holds config.json, checkpoints/, metrics.jsonl
(each step's loss and its terms) and TensorBoard files, like a training run folder; running
the same command again resumes from its newest checkpoint. The bundle's PROVENANCE.json says
that it was adapted, from which model, on which frames and with which weights. Predict with
it on the same rig ('gijax predict --ckpt OUT --rig RIG --panorama hemisphere ...').
"""


def register(subparsers) -> None:
    from gijax.cli.options import CKPT_HELP, RawHelpFormatter, add_rig_option

    p = subparsers.add_parser("adapt", help=HELP, formatter_class=RawHelpFormatter,
                              description=DESCRIPTION)
    p.add_argument("--ckpt", required=True, metavar="PATH|NAME",
                   help="the model to adapt: " + CKPT_HELP)
    p.add_argument("--frames", required=True, nargs="+", metavar="DIR",
                   help="frame folders (one image per camera, named after the rig's cameras) "
                        "and/or gijax dataset folders (their labels unused)")
    add_rig_option(p, default_help="the first dataset's rig; needed for frame folders")
    p.add_argument("--out", required=True, metavar="BUNDLE",
                   help="adapted bundle folder to write (new, or an earlier bundle, replaced)")
    p.add_argument("--photometric", type=float, default=1.0,
                   help="weight of the photometric consistency across cameras")
    p.add_argument("--smoothness", type=float, default=0.01,
                   help="weight of the edge-aware smoothness of the inverse distance")
    p.add_argument("--edge", type=float, default=10.0, metavar="EDGE",
                   help="how fast a colour edge frees the smoothness: exp(-EDGE |dI|), colours "
                        "in [0, 1]")
    p.add_argument("--no-gain-normalisation", action="store_true",
                   help="compare the cameras' colours as they are; by default each camera's "
                        "colours are first scaled to the cameras' common mean (cameras differ "
                        "in exposure and white balance, which would hide the distance)")
    from gijax.geometry.visibility import OCCLUSION_MARGIN

    p.add_argument("--occlusion", type=float, default=OCCLUSION_MARGIN, metavar="MARGIN",
                   help="compare a camera's colour at a predicted point only where no nearer "
                        "predicted point hides it from that camera, MARGIN being how much "
                        "farther (relative, in inverse distance) than the nearest point in its "
                        f"direction it may lie and still count as seen (default "
                        f"{OCCLUSION_MARGIN:g}, as 'gijax rig refine'; 0: every camera that "
                        "images the point is compared). Cameras a baseline apart see different "
                        "stretches of a wall behind a post: on renders of a 0.5 m ring, "
                        "adapting without the test did not lower the held-out error, with it "
                        "it did")
    p.add_argument("--teacher", type=float, default=0.0,
                   help="weight of the classical baseline as a teacher where it is trusted "
                        "(0: no teacher; it is then not run)")
    from gijax.baseline.rtss import RTSS_PRESETS

    p.add_argument("--teacher-preset", default="RS-E32", choices=sorted(RTSS_PRESETS),
                   metavar="NAME",
                   help=f"the classical baseline that teaches with --teacher "
                        f"({', '.join(RTSS_PRESETS)})")
    p.add_argument("--teacher-max-dispersion", type=float, default=0.02, metavar="D",
                   help="trust the teacher where the cameras' colour dispersion at its "
                        "distance is at most D (the photometric term's units)")
    p.add_argument("--steps", type=int, default=200, help="Adam steps in total")
    p.add_argument("--lr", type=float, default=2e-5, help="Adam learning rate (constant)")
    p.add_argument("--batch", type=int, default=1, help="frames per step")
    p.add_argument("--seed", type=int, default=0, help="frame order")
    p.add_argument("--batch-norm", choices=("frozen", "train"), default="frozen",
                   help="'frozen': BatchNorm keeps the model's running statistics (as at "
                        "inference; for few frames and small batches); 'train': batch "
                        "statistics, running averages updated")
    p.add_argument("--max-frames", type=int, default=64,
                   help="use at most this many frames (the first ones)")
    p.add_argument("--ckpt-every", type=int, default=25, help="steps between checkpoints")
    p.add_argument("--val", metavar="DATASET",
                   help="labelled dataset of the rig to score on (a validation score only, "
                        "never in the objective)")
    p.add_argument("--val-every", type=int, default=0,
                   help="steps between validations with --val (0: before and at the end only)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args) -> int:
    from gijax.bench.machine import invocation
    from gijax.train.rig_adaptation import adapt_network, work_folder
    from gijax.train.unlabeled import LabelFree

    if args.max_frames < 1:
        raise ValueError(f"--max-frames must be >= 1; found {args.max_frames}")
    if not args.teacher_max_dispersion > 0:
        raise ValueError(f"--teacher-max-dispersion must be > 0; found "
                         f"{args.teacher_max_dispersion}")
    objective = LabelFree(photometric=args.photometric, smoothness=args.smoothness,
                          teacher=args.teacher, edge_scale=args.edge,
                          normalize_gain=not args.no_gain_normalisation,
                          occlusion=args.occlusion)
    args.interrupted_keeps = (f"{work_folder(args.out)} keeps the checkpoints written so far; "
                              f"the same command resumes from the last")
    result = adapt_network(
        args.ckpt, args.frames, args.out, rig=args.rig, objective=objective, steps=args.steps,
        lr=args.lr, batch_size=args.batch, seed=args.seed, batch_norm=args.batch_norm,
        ckpt_every=args.ckpt_every, max_frames=args.max_frames,
        teacher_preset=args.teacher_preset, teacher_max_dispersion=args.teacher_max_dispersion,
        val=args.val, val_every=args.val_every, progress=not args.no_progress,
        invocation=invocation(shlex.join(["gijax", *args.argv])))
    losses = [r for r in result.history if "loss" in r]
    if losses:
        k = max(1, min(10, len(losses) // 4))
        first = sum(r["loss"] for r in losses[:k]) / k
        last = sum(r["loss"] for r in losses[-k:]) / k
        print(f"label-free loss: first {k} steps {first:.5f}, last {k} steps {last:.5f}")
    vals = [r for r in result.history if r.get("split") == "val"]
    if args.val and (result.before or vals):
        def text(m):
            return f"MAE {m['mae']:.4f}  RMSE {m['rmse']:.4f} (inverse distance, 1/m)"

        print(f"validation (labels of {args.val}; a score only, not used for adapting):")
        if result.before:
            print(f"  before: {text(result.before)}")
        if vals:
            print(f"  step {vals[-1]['step']}: {text(vals[-1])}")
    print(f"adapted {result.step} steps on {len(result.frames)} frame(s); run folder "
          f"{result.work}")
    print(f"wrote {result.bundle}")
    return 0
