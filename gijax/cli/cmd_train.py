"""``gijax train``: train a network preset on a dataset folder, resumable, on all devices."""

from __future__ import annotations

from gijax.cli.options import (HelpFormatter, add_candidates_option, add_rig_option,
                               field_value)


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
        formatter_class=HelpFormatter)
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
                   choices=["constant", "cosine", "warmup_cosine", "step"],
                   help="learning-rate schedule over --steps: constant, cosine decay, linear "
                        "warm-up from zero then cosine decay, or staircase exponential decay")
    p.add_argument("--warmup-steps", type=int, default=0,
                   help="steps of linear learning-rate warm-up (--schedule warmup_cosine)")
    p.add_argument("--clip-norm", type=float, default=None, help="clip the global gradient norm")
    p.add_argument("--grad-accum", type=int, default=1, help="micro-batches per step")
    p.add_argument("--bf16", action="store_true", help="bfloat16 compute (GPUs)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the model initialisation and the data order")
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
    add_candidates_option(p, None, "the preset's own kind ('train': EV, or GI with the "
                                   "paper's baseline); keywords are resolved once for the "
                                   "training rig (--rig, else the first dataset's)",
                          what="the list to train with")
    p.add_argument("--learn-candidates", action="store_true",
                   help="train the candidate list with the network (its ends kept; its own "
                        "Adam at --candidates-lr); the learned list is logged at each "
                        "validation, written to RUN/candidates.json and used by eval, predict "
                        "and export of the run (docs/candidates.md, Learned lists)")
    p.add_argument("--candidates-lr", type=float, default=1e-2,
                   help="learning rate of the learned list's logits")
    p.add_argument("--init-from", default=None, metavar="CKPT",
                   help="start from a trained model instead of random weights (a run folder, "
                        "a bundle, a resume pack or a bundled model's name, e.g. G16VV-cpu): "
                        "fine-tuning with "
                        "a fresh optimiser and schedule; its network must be --preset's (with "
                        "--override). A run folder with a checkpoint resumes from that instead")
    p.add_argument("--pack", default=None, metavar="DIR",
                   help="resume pack: rewritten at every checkpoint with what the next piece "
                        "of the run needs (weights, BatchNorm statistics, Adam's moments, step, "
                        "data position, log; about 12 MB for a -cpu preset), small enough to "
                        "commit; a run whose folder is missing or older resumes from it "
                        "(docs/training.md, Training in pieces)")
    add_rig_option(p, default_help="the dataset's rig; one --data folder only")
    p.add_argument("--coordinator", default=None, help="host:port of process 0 (multi-host)")
    p.add_argument("--num-processes", type=int, default=None,
                   help="number of processes of a multi-host run (with --coordinator)")
    p.add_argument("--process-id", type=int, default=None,
                   help="this process's index, 0 .. --num-processes - 1 (multi-host)")
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
    import dataclasses
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
        init_from=args.init_from, pack=args.pack)
    cfg = dataclasses.replace(cfg, candidates=_training_list(args, cfg))
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


def _training_list(args, cfg):
    """--candidates as a list of metres (None: the preset's own kind, decided by the trainer).
    A keyword is resolved once, here, for the training rig (--rig, else the first dataset's,
    in the dataset's panorama frame as the trainer uses it)."""
    from gijax.candidates.spec import KEYWORDS, TRAIN, model_candidates, resolve_candidates

    if args.candidates in (None, TRAIN):
        return None
    mc = cfg.model_config()
    if args.candidates not in KEYWORDS:
        # A file of any length here: the trainer reports a count that does not fit the preset.
        return resolve_candidates(args.candidates, None, mc.num_candidates,
                                  any_count=True)[0].tolist()
    rig = None
    if args.candidates in ("spacing", "rig"):      # the recomputed lists that need the rig
        from gijax.train.sources import open_dataset

        reader = open_dataset(args.data[0], "training", args.allow_partial)
        rig = reader.rig
        if args.rig:
            from gijax.io.rigfile import load_rig

            rig = load_rig(args.rig).replace(panorama_rotation=rig.panorama_rotation)
    cand, how = model_candidates(args.candidates, rig, mc)
    print(f"training candidates: {how}; {len(cand)} from {cand[0]:.3f} to {cand[-1]:.3f} m")
    return cand.tolist()
