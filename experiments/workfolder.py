"""The shared work folder (``--work``): rendered datasets under ``data/`` and training runs under
``runs/``, each made, resumed or reused by calling the library the ``gijax render`` and ``gijax
train`` commands are made of.

Everything is resumable: a dataset continues after its last complete sample, an interrupted
training resumes from the trainer's newest checkpoint, and a finished training
(``runs/<preset>.done.json``) is reused as it is when its command is unchanged. Each record
names the equivalent ``gijax`` command, which also keys the reuse.
"""

from __future__ import annotations

import dataclasses
import json
import shlex
import time
from pathlib import Path
from typing import Optional

from experiments.reporting import log, read_json, write_json
from experiments.scales import DATA_SEEDS, DATA_STYLE, Scale, model_overrides, preset_name


def gijax_command(argv: list) -> str:
    """The shell command line of a ``gijax`` call's arguments (it also keys reuse)."""
    return "gijax " + shlex.join(map(str, argv))


# --------------------------------------------------------------------------- data

def rig_file_argument(work: Path, name: str, make_rig) -> str:
    """What ``gijax render --rig`` takes for a rig that is not built in: its rig file
    ``rigs/<name>.yaml`` in the work folder, written once from ``make_rig()``, so that the
    recorded command reproduces the data."""
    from gijax.io.rigfile import save_rig

    path = work / "rigs" / f"{name}.yaml"
    if not path.is_file():
        save_rig(make_rig(), path)
    return str(path)


def render_argv(rig: str, samples: int, seed: int, out: Path, image_scale: float,
                pano_hw: tuple, style: str = DATA_STYLE,
                lens_seed: Optional[int] = None) -> list:
    """The ``gijax render`` command of a dataset: ``rig`` as ``--rig`` takes it (a built-in
    name or a rig file), ``pano_hw`` the panorama's (height, width), ``lens_seed`` a drawn lens
    (``--lens random``)."""
    h, w = pano_hw
    argv = ["render", "--rig", rig, "--samples", samples, "--out", out, "--seed", seed,
            "--scale", image_scale, "--pano", f"{w}x{h}", "--style", style]
    if lens_seed is not None:
        argv += ["--lens", "random", "--lens-seed", lens_seed]
    return argv


def render_recorded(rig, rig_arg: str, out: Path, samples: int, seed: int, image_scale: float,
                    pano_hw: tuple, style: str = DATA_STYLE, lens_seed: Optional[int] = None,
                    progress: bool = True) -> dict:
    """Render (or resume, or reuse) a dataset by calling the library ``gijax render`` is made
    of, and name the command that does the same: ``rig`` is the Rig rendered (with a drawn
    lens already applied), ``rig_arg`` and ``lens_seed`` what the command says for it.
    Returns ``{"command": ..., "seconds": ...}`` (wall seconds, 0-ish when reused)."""
    from gijax.data.rendered import render_dataset
    from gijax.geometry.panorama import Panorama

    t0 = time.perf_counter()
    render_dataset(rig, out, samples, seed=seed, image_scale=image_scale,
                   pano=Panorama.hemisphere(*pano_hw), style=style, progress=progress, log=log)
    argv = render_argv(rig_arg, samples, seed, out, image_scale, pano_hw, style, lens_seed)
    return {"command": gijax_command(argv), "seconds": time.perf_counter() - t0}


def ensure_dataset(work: Path, scale: Scale, role: str) -> dict:
    """Render (or resume, or reuse) one dataset of the work folder; returns its record.

    ``role`` is 'train', 'val' or a test rig name.
    """
    from gijax.geometry.layouts import builtin_rig

    rig = "paper-train" if role in ("train", "val") else role
    samples = {"train": scale.train_samples, "val": scale.val_samples}.get(role)
    if samples is None:
        samples = scale.test_samples[role]
    out = work / "data" / role
    made = render_recorded(builtin_rig(rig), rig, out, samples, DATA_SEEDS[role],
                           scale.image_scale, scale.pano_hw, progress=scale.progress)
    return {"role": role, "rig": rig, "path": str(out), "samples": samples,
            "seed": DATA_SEEDS[role], "style": DATA_STYLE, **made}


def dataset_seeds(path: Path) -> list:
    """The render seeds recorded for the samples of a dataset folder."""
    from gijax.data import DatasetReader
    from gijax.data.format import read_file_list

    reader = DatasetReader(path, verify="none")
    return [int(row["seed"]) for t in reader.manifest["trajectories"]
            for row in read_file_list(reader.root / t["file_list"], reader.names)
            if row.get("seed")]


def check_held_out(work: Path, tests: list) -> dict:
    """Sample seeds shared between the training/validation data and each test set (must be 0)."""
    seen = set(dataset_seeds(work / "data" / "train"))
    if (work / "data" / "val").exists():
        seen |= set(dataset_seeds(work / "data" / "val"))
    overlap = {t: len(seen & set(dataset_seeds(work / "data" / t))) for t in tests}
    bad = {t: n for t, n in overlap.items() if n}
    if bad:
        raise ValueError(f"test data shares scene seeds with the training data: {bad}")
    return overlap


def style_counts(path: Path) -> dict:
    """How many samples of a 'mixed' dataset are indoor and outdoor scenes."""
    from gijax.render.render import choose_style

    counts = {"indoor": 0, "outdoor": 0}
    for s in dataset_seeds(path):
        counts[choose_style(s, DATA_STYLE)] += 1
    return counts


# --------------------------------------------------------------------------- training

def run_folder(work: Path, scale: Scale, model: str, learned: bool = False) -> Path:
    """A model's run folder; a run that learns its candidate list has its own."""
    return work / "runs" / (preset_name(scale, model) + ("-learned" if learned else ""))


def train_argv(work: Path, scale: Scale, model: str, seed: int,
               candidates_lr: float | None = None) -> list:
    """The ``gijax train`` command equivalent to :func:`ensure_trained`'s call; with
    ``candidates_lr`` the list is learned too, at the same data, steps, batch, learning rate,
    validation and seed."""
    preset = preset_name(scale, model)
    argv = ["train", "--preset", preset, "--data", work / "data" / "train",
            "--out", run_folder(work, scale, model, candidates_lr is not None),
            "--steps", scale.steps, "--batch", scale.batch, "--lr", scale.lr,
            "--val-every", scale.val_every, "--ckpt-every", scale.ckpt_every,
            "--seed", seed, "--workers", _workers(scale)]
    if scale.val_samples:
        argv += ["--val", work / "data" / "val"]
    for k, v in model_overrides(scale, model).items():
        argv += ["--override", f"{k}={json.dumps(v, separators=(',', ':'))}"]
    if not scale.progress:
        argv.append("--no-progress")
    if candidates_lr is not None:
        argv += ["--learn-candidates", "--candidates-lr", candidates_lr]
    return argv


def _workers(scale: Scale) -> int:
    return 1 if scale.tiny else 2


def train_config(scale: Scale, model: str, seed: int):
    """The :class:`~gijax.train.config.TrainConfig` of :func:`train_argv`'s command (every other
    field at the command's default)."""
    from gijax.train.config import TrainConfig

    return TrainConfig(preset=preset_name(scale, model),
                       model_overrides=model_overrides(scale, model), lr=scale.lr,
                       batch_size=scale.batch, steps=scale.steps, seed=seed,
                       val_every=scale.val_every, ckpt_every=scale.ckpt_every,
                       keep_best=bool(scale.val_samples), workers=_workers(scale))


def metrics_records(run_dir: Path) -> list:
    """The records of a run's ``metrics.jsonl`` (a line cut by an interruption is skipped)."""
    path = run_dir / "metrics.jsonl"
    out = []
    if path.is_file():
        for line in path.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue            # a line cut by an interruption
    return out


def last_logged_step(run_dir: Path) -> int:
    return max([int(r["step"]) for r in metrics_records(run_dir) if "loss" in r], default=0)


def last_validation(run_dir: Path) -> Optional[dict]:
    vals = [r for r in metrics_records(run_dir) if r.get("split") == "val"]
    return vals[-1] if vals else None


def train_run(run_dir: Path, command: str, config, data, val: Optional[Path], progress: bool,
              record: dict, stop_at: Optional[int] = None) -> dict:
    """Train ``config`` on ``data`` into ``run_dir`` (resuming after its newest checkpoint, or
    from ``config.pack``), or reuse the finished run when its done-record holds the same
    ``command`` and step count. Returns the done-record: ``record`` plus the command, timing
    and last validation. ``stop_at`` < ``config.steps`` trains one piece of the run and
    returns its record with ``"finished": False`` (no done-record is written)."""
    from gijax.bench.machine import invocation
    from gijax.train.entry import train

    done_file = run_dir.with_name(run_dir.name + ".done.json")
    done = read_json(done_file)
    if done and done.get("command") == command and done.get("steps") == config.steps:
        log(f"  {run_dir.name}: reusing the finished run {run_dir}")
        return {**done, "reused": True}
    start = last_logged_step(run_dir)
    log(f"  {run_dir.name}: training {config.steps} steps" +
        (" with the list learned" if config.learn_candidates else "") +
        (f" (resuming after step {start})" if start else "") + f" -> {run_dir}")
    t0 = time.perf_counter()
    partial = stop_at is not None and stop_at < config.steps
    if partial and start >= stop_at:
        return {**record, "run": str(run_dir), "command": command, "finished": False,
                "reused": True}
    train(config, data, run_dir, val=val, progress=progress, invocation=invocation(command),
          stop_at=stop_at if partial else None)
    seconds = time.perf_counter() - t0
    if partial:
        return {**record, "run": str(run_dir), "command": command, "finished": False,
                "train_seconds": seconds, "reused": False}
    out = {**record, "run": str(run_dir), "command": command, "steps": config.steps,
           "resumed_from_step": start, "train_seconds": seconds,
           "seconds_per_step": seconds / max(config.steps - start, 1),
           "validation": last_validation(run_dir), "finished_unix": time.time()}
    if config.learn_candidates:
        out["final_candidates"] = (read_json(run_dir / "candidates.json") or {}).get("candidates")
    write_json(done_file, out)
    return {**out, "reused": False}


def ensure_trained(work: Path, scale: Scale, model: str, seed: int,
                   candidates_lr: float | None = None) -> dict:
    """Train one model to ``scale.steps`` (resuming), or reuse a finished run; its record.
    With ``candidates_lr`` the candidate list is learned too (its own run folder), and the
    record holds the final list."""
    learned = candidates_lr is not None
    config = train_config(scale, model, seed)
    if learned:
        config = dataclasses.replace(config, learn_candidates=True, candidates_lr=candidates_lr)
    return train_run(run_folder(work, scale, model, learned),
                     gijax_command(train_argv(work, scale, model, seed, candidates_lr)), config,
                     work / "data" / "train",
                     work / "data" / "val" if scale.val_samples else None, scale.progress,
                     {"model": model, "preset": preset_name(scale, model)})
