"""``gijax train``: train a network preset on a dataset folder, resumable, on all devices."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


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
    p.add_argument("--data", required=True,
                   help="training dataset folder, gijax's layout or the release's (partition "
                        "'train'; DIR@KEY reads partition KEY)")
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
    p.add_argument("--workers", type=int, default=2, help="data loader threads")
    p.add_argument("--candidates", default=None,
                   help="JSON file with a list of distances (m); default: the preset's kind "
                        "computed for the training rig")
    p.add_argument("--rig", default=None, help="rig name or file (default: the dataset's rig)")
    p.add_argument("--coordinator", default=None, help="host:port of process 0 (multi-host)")
    p.add_argument("--num-processes", type=int, default=None)
    p.add_argument("--process-id", type=int, default=None)
    p.add_argument("--override", action="append", default=[], metavar="FIELD=VALUE",
                   help="replace a network configuration field of the preset (JSON value), "
                        "e.g. --override 'cost_hw=[8,32]'; repeatable")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-data-check", action="store_true",
                   help="skip reading every dataset file before training (damaged files are "
                        "then found when the loader reaches them)")
    p.add_argument("--allow-partial", action="store_true",
                   help="train on datasets holding fewer samples than their manifest requests")
    p.set_defaults(func=run)


def read_candidate_file(path: str) -> list:
    """A JSON list of distances (metres) or a text file of numbers (one per line or comma
    separated); a JSON object is read through its ``candidates`` key."""
    f = Path(path)
    if not f.is_file():
        raise FileNotFoundError(f"candidate file {f} does not exist")
    text = f.read_text()
    try:
        values = json.loads(text)
    except json.JSONDecodeError:
        try:
            values = [float(t) for t in text.replace(",", " ").split()]
        except ValueError as exc:
            raise ValueError(f"candidate file {f}: expected a JSON list or one number per line "
                             f"({exc})") from exc
    if isinstance(values, dict):
        values = values.get("candidates")
    if not isinstance(values, list) or not values:
        raise ValueError(f"candidate file {f}: expected a non-empty list of distances in metres")
    return [float(v) for v in values]


def parse_overrides(items) -> dict:
    """``['a=1', 'b=[2,3]']`` -> ``{'a': 1, 'b': [2, 3]}`` (values are JSON, else strings)."""
    out = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"--override expects FIELD=VALUE; found {item!r}")
        key, value = item.split("=", 1)
        try:
            out[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            out[key.strip()] = value
    return out


def check_data(reader, what: str, args) -> None:
    """Read every file of a gijax-layout dataset before training (``--no-data-check`` skips)."""
    from gijax.data import DatasetReader

    if not args.no_data_check and isinstance(reader, DatasetReader):
        from gijax.cli.cmd_data import require_clean

        require_clean(reader.root, what, args.allow_partial, not args.no_progress)


def run(args) -> int:
    from gijax.io.paths import check_output_dir
    from gijax.train.trainer import init_distributed

    check_output_dir(args.out)
    init_distributed(args.coordinator, args.num_processes, args.process_id)
    from gijax.train.config import TrainConfig
    from gijax.train.sources import (dataset_stream_factory, open_dataset, validation_batches)
    from gijax.train.trainer import Trainer

    cfg = TrainConfig(
        preset=args.preset, model_overrides=parse_overrides(args.override), lr=args.lr, schedule=args.schedule, warmup_steps=args.warmup_steps,
        clip_norm=args.clip_norm, batch_size=args.batch, grad_accum=args.grad_accum,
        steps=args.steps, seed=args.seed, bf16=args.bf16, val_every=args.val_every,
        val_batches=args.val_batches, ckpt_every=args.ckpt_every, keep=args.keep,
        keep_best=bool(args.val), workers=args.workers,
        candidates=read_candidate_file(args.candidates) if args.candidates else None)
    mc = cfg.model_config()
    reader = open_dataset(args.data, "training", args.allow_partial)
    check_data(reader, "training", args)
    if args.rig:
        from gijax.io.rigfile import load_rig

        rig = load_rig(args.rig)
    else:
        rig = reader.rig
    make_stream = dataset_stream_factory(reader, rig, cfg.batch_size, cfg.seed, mc.surrogate_hw,
                                         mask_augmentation=mc.mask_augmentation,
                                         workers=cfg.workers)
    make_val, val_rig = None, None
    if args.val:
        val_reader = open_dataset(args.val, "validation", args.allow_partial)
        check_data(val_reader, "validation", args)
        make_val = lambda: validation_batches(val_reader, val_reader.rig, cfg.batch_size,  # noqa: E731
                                              mc.surrogate_hw, cfg.val_batches)
        val_rig = val_reader.rig
    trainer = Trainer(cfg, args.out, rig, make_stream, make_val, rig_name=args.rig or str(args.data),
                      progress=not args.no_progress, val_rig=val_rig)
    try:
        history = trainer.fit()
    finally:
        trainer.close()
    losses = [r["loss"] for r in history if "loss" in r]
    vals = [r for r in history if r.get("split") == "val"]
    if losses:
        print(f"trained {args.out} to step {trainer.start_step}: last loss {losses[-1]:.5f}")
    if vals:
        v = vals[-1]
        print(f"validation at step {v['step']}: MAE {v['mae']:.4f}  RMSE {v['rmse']:.4f}  "
              f"SSIM {v['ssim']:.4f} (inverse distance, 1/m)")
    return 0
