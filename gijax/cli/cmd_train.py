"""``gijax train``: train a network preset on a dataset folder, resumable, on all devices."""

from __future__ import annotations

import argparse

from gijax.cli.options import field_value


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "train", help="train a network on a dataset folder (resumes an existing run folder)",
        description=(
            "Train a network preset on a gijax dataset folder. The run folder (--out) receives "
            "config.json, checkpoints/ (newest --keep), best/ (best validation MAE), "
            "metrics.jsonl, TensorBoard event files in tb/ and sample predictions in samples/. "
            "Running the same command again resumes from the newest readable checkpoint, with "
            "the same data order; metrics.jsonl and the TensorBoard files then hold each step "
            "once. Before training, every file of the datasets is checked ('gijax data check'; "
            "--no-data-check skips it) and incomplete datasets are refused (--allow-partial "
            "accepts them). The run folder is locked while training: a second 'gijax train' "
            "on it fails naming the first one's PID. Batches are split over all devices (data "
            "parallel); for several hosts start one process per host with --coordinator, "
            "--num-processes and --process-id."),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--preset", required=True, help="network preset, e.g. G16VV-cpu or G16VV")
    p.add_argument("--data", required=True, nargs="+", metavar="DIR",
                   help="training dataset folder, gijax's layout or the release's (partition "
                        "'train'; DIR@KEY reads partition KEY); several folders (other rigs, "
                        "other lenses) are mixed, one folder per batch in proportion to their "
                        "sizes, each with its own rig")
    p.add_argument("--val", help="validation dataset folder (optional)")
    p.add_argument("--out", required=True, help="run folder")
    p.add_argument("--steps", type=int, default=1000, help="optimiser steps in total")
    p.add_argument("--batch", type=int, default=2, help="global batch size (all devices)")
    p.add_argument("--lr", type=float, default=1e-4, help="Adam learning rate")
    p.add_argument("--schedule", default="constant",
                   choices=["constant", "cosine", "warmup_cosine", "step"])
    p.add_argument("--warmup-steps", type=int, default=0)
    p.add_argument("--clip-norm", type=float, default=None, help="clip the global gradient norm")
    p.add_argument("--grad-accum", type=int, default=1, help="micro-batches per step")
    p.add_argument("--bf16", action="store_true", help="bfloat16 compute (GPUs)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--val-every", type=int, default=500, help="steps between validations")
    p.add_argument("--val-batches", type=int, default=0, help="limit validation batches (0: all)")
    p.add_argument("--ckpt-every", type=int, default=100, help="steps between checkpoints")
    p.add_argument("--keep", type=int, default=3, help="periodic checkpoints kept")
    p.add_argument("--augment", default="none",
                   choices=["none", "photometric", "photometric+body"],
                   help="augment the training fisheyes (never validation): sensor noise, blur, "
                        "exposure / white balance / gamma, vignetting, JPEG; '+body' adds random "
                        "rig-body outlines to the masks (docs/data.md, Augmentations)")
    p.add_argument("--calibration-error", type=float, default=0.0, metavar="DEG",
                   help="tell the network a rig whose cameras are turned by random rotations "
                        "of up to DEG degrees, new each step (images, labels and validation "
                        "keep the true rig): tolerance to calibration error (docs/data.md)")
    p.add_argument("--workers", type=int, default=2, help="data loader threads")
    p.add_argument("--candidates", default=None,
                   help="JSON file with a list of distances (m); default: the preset's kind "
                        "computed for the training rig")
    p.add_argument("--learn-candidates", action="store_true",
                   help="train the candidate list with the network (its ends kept; its own "
                        "Adam at --candidates-lr); the learned list is logged at each "
                        "validation, written to RUN/candidates.json and used by eval, predict "
                        "and export of the run (docs/candidates.md, Learned lists)")
    p.add_argument("--candidates-lr", type=float, default=1e-2,
                   help="learning rate of the learned list's logits")
    p.add_argument("--init-from", default=None, metavar="CKPT",
                   help="start from a trained model instead of random weights (a run folder, "
                        "a bundle or a bundled model's name, e.g. G16VV-cpu): fine-tuning with "
                        "a fresh optimiser and schedule; its network must be --preset's (with "
                        "--override). A run folder with a checkpoint resumes from that instead")
    p.add_argument("--pack", default=None, metavar="DIR",
                   help="resume pack: rewritten at every checkpoint with what the next piece "
                        "of the run needs (weights, BatchNorm statistics, Adam's moments, step, "
                        "data position, log; about 12 MB for a -cpu preset), small enough to "
                        "commit; a run whose folder is missing or older resumes from it "
                        "(docs/training.md, Training in pieces)")
    p.add_argument("--rig", default=None, help="rig name or file (default: the dataset's rig)")
    p.add_argument("--coordinator", default=None, help="host:port of process 0 (multi-host)")
    p.add_argument("--num-processes", type=int, default=None)
    p.add_argument("--process-id", type=int, default=None)
    p.add_argument("--override", action="append", type=field_value, default=[],
                   metavar="FIELD=VALUE",
                   help="replace a network configuration field of the preset (JSON value), "
                        "e.g. --override 'cost_hw=[8,32]'; repeatable")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-data-check", action="store_true",
                   help="skip reading every dataset file before training (damaged files are "
                        "then found when the loader reaches them)")
    p.add_argument("--allow-partial", action="store_true",
                   help="train on datasets holding fewer samples than their manifest requests")
    p.set_defaults(func=run)


def run(args) -> int:
    import shlex

    from gijax.bench.machine import invocation
    from gijax.io.paths import check_output_dir
    from gijax.train.trainer import init_distributed

    check_output_dir(args.out)
    if args.pack:
        check_output_dir(args.pack, "--pack")
    args.interrupted_keeps = (f"{args.out} keeps the checkpoints written so far (every "
                              f"--ckpt-every steps); the same command resumes from the last")
    init_distributed(args.coordinator, args.num_processes, args.process_id)
    from gijax.candidates.spec import read_candidate_file
    from gijax.train.config import TrainConfig
    from gijax.train.entry import train

    cfg = TrainConfig(
        preset=args.preset, model_overrides=dict(args.override), lr=args.lr,
        schedule=args.schedule, warmup_steps=args.warmup_steps, clip_norm=args.clip_norm,
        batch_size=args.batch, grad_accum=args.grad_accum, steps=args.steps, seed=args.seed,
        bf16=args.bf16, val_every=args.val_every, val_batches=args.val_batches,
        ckpt_every=args.ckpt_every, keep=args.keep, keep_best=bool(args.val),
        workers=args.workers, augment=args.augment,
        calibration_error_deg=args.calibration_error,
        learn_candidates=args.learn_candidates, candidates_lr=args.candidates_lr,
        init_from=args.init_from, pack=args.pack,
        candidates=read_candidate_file(args.candidates).tolist() if args.candidates else None)
    data = args.data[0] if len(args.data) == 1 else args.data
    result = train(cfg, data, args.out, val=args.val, rig=args.rig,
                   allow_partial=args.allow_partial, check_data=not args.no_data_check,
                   progress=not args.no_progress,
                   invocation=invocation(shlex.join(["gijax", *args.argv])))
    if result.last_loss is not None:
        print(f"trained {args.out} to step {result.step}: last loss {result.last_loss:.5f}")
    v = result.last_validation
    if v is not None:
        print(f"validation at step {v['step']}: MAE {v['mae']:.4f}  RMSE {v['rmse']:.4f}  "
              f"SSIM {v['ssim']:.4f} (inverse distance, 1/m)")
    return 0
