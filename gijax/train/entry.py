"""Training a run folder from a :class:`TrainConfig` and dataset folders: ``gijax train`` as a
function (the command parses its options into a config and calls :func:`train`; the
experiments call it directly)."""

from __future__ import annotations

import concurrent.futures
import dataclasses
import os
from pathlib import Path
from typing import NamedTuple, Optional

from gijax.train.config import TrainConfig


class TrainingResult(NamedTuple):
    step: int              # optimiser steps done (the run's step after this call)
    history: list          # the records logged by this call (training and validation)

    @property
    def last_loss(self) -> Optional[float]:
        losses = [r["loss"] for r in self.history if "loss" in r]
        return losses[-1] if losses else None

    @property
    def last_validation(self) -> Optional[dict]:
        vals = [r for r in self.history if r.get("split") == "val"]
        return vals[-1] if vals else None


def fit_panorama(config: TrainConfig, reader, log=None):
    """The training configuration and model configuration for the dataset's label panorama.

    The model is trained on the part of the sphere its labels cover: a preset made for the
    hemisphere trained on full-sphere labels becomes a sphere model at the same angular
    resolution (``panorama``, ``cost_hw`` and ``output_hw`` overridden, said through ``log``).
    Labels of another size than the model's output are refused, naming both.
    """
    from gijax.geometry.panorama_frame import coverage_of
    from gijax.model import model_panorama

    mc = config.model_config()
    label = getattr(reader, "pano", None)
    if label is None:
        return config, mc
    coverage = coverage_of(label)
    if coverage != mc.panorama:
        h, w = model_panorama(mc, coverage).shape
        over = dict(config.model_overrides, panorama=coverage, output_hw=[h, w],
                    cost_hw=[h // mc.output_stride, w // mc.output_stride])
        config = dataclasses.replace(config, model_overrides=over)
        mc = config.model_config()
        if log is not None:
            log(f"note: the training labels cover the {coverage}; {mc.name} is trained on it "
                f"(panorama={coverage}, output {h}x{w})")
    if tuple(label.shape) != tuple(mc.output_hw):
        raise ValueError(f"the training labels are {label.height} x {label.width} panoramas but "
                         f"model {mc.name!r} outputs {mc.output_hw[0]} x {mc.output_hw[1]}; "
                         f"render the data at the model's size (gijax render --pano "
                         f"{mc.output_hw[1]}x{mc.output_hw[0]}) or override output_hw and "
                         f"cost_hw")
    return config, mc


def train(config: TrainConfig, data, out: str | os.PathLike, *,
          val: str | os.PathLike | None = None, rig: str | None = None,
          allow_partial: bool = False, check_data: bool = True,
          progress: bool = True, invocation: dict | None = None,
          stop_at: int | None = None) -> TrainingResult:
    """Train (or resume) the run folder ``out`` on dataset ``data`` until ``config.steps``.

    Args:
      config: how to train (``keep_best`` only takes effect with ``val``).
      data / val: training and validation dataset folders, gijax's layout or the release's
        (``DIR@KEY`` reads partition KEY). ``data`` may be a list of folders, each with its
        own rig (other layouts, other lenses): each batch then comes from one of them, drawn
        in proportion to their sizes (:class:`gijax.train.sources.MixedStream`); their labels
        must be panoramas of one size and coverage, and the first folder's rig sets the GI
        candidates.
      rig: rig name or file for the sweep geometry (default: the training dataset's rig; one
        training dataset only).
      allow_partial: accept datasets holding fewer samples than their manifest requests.
      check_data: read every file of gijax-layout datasets first (a damaged file then fails
        before training, not when the loader reaches it).
      progress: progress bars.
      stop_at: end this piece after that many steps in all (default ``config.steps``); the
        schedule is still ``config.steps`` long, and the same call without it (or with a later
        ``stop_at``) continues the run.
      invocation: what started this piece of the run (e.g. the command and code revision,
        :func:`gijax.bench.machine.invocation`), logged in ``metrics.jsonl`` with its start
        or resume event.
    """
    from gijax.data import DatasetReader
    from gijax.data.augment import augment_preset
    from gijax.data.check import require_clean
    from gijax.io.paths import check_output_dir
    from gijax.train.sources import (dataset_stream_factory, mixed_stream_factory, open_dataset,
                                     validation_batches)
    from gijax.train.run_folder import check_run_folder, run_candidates
    from gijax.train.trainer import Trainer

    check_output_dir(out)
    check_run_folder(Path(out))          # before the data are read: never into another folder
    mc = config.model_config()

    def opened(path, what):
        reader = open_dataset(path, what, allow_partial)
        if check_data and isinstance(reader, DatasetReader):
            require_clean(reader.root, what, allow_partial, progress)
        return reader

    datas = [data] if isinstance(data, (str, os.PathLike)) else list(data)
    if not datas:
        raise ValueError("no training dataset given")
    if rig and len(datas) > 1:
        raise ValueError(f"a rig file (--rig {rig}) applies to one training dataset; "
                         f"{len(datas)} were given, each is trained with its own rig")
    readers = [opened(d, "training") for d in datas]
    reader = readers[0]
    for d, other in zip(datas[1:], readers[1:]):
        if _pano_text(other) != _pano_text(reader):
            raise ValueError(f"training datasets {datas[0]} and {d} have different label "
                             f"panoramas ({_pano_text(reader)} vs {_pano_text(other)}); "
                             f"render them at one size and coverage")
    # The run's list, resolved once: the run folder's own on resume, else the configuration's
    # (a bad list is reported before anything else about the data).
    candidates = run_candidates(config, out, reader.rig)
    config, mc = fit_panorama(config, reader, log=print if progress else None)
    if rig:
        from gijax.io.rigfile import load_rig

        # The labels fix the panorama frame: the dataset's, whatever the rig file says.
        train_rig = load_rig(rig).replace(panorama_rotation=reader.rig.panorama_rotation)
    else:
        train_rig = reader.rig

    # Several datasets load in one pool of ``workers`` threads, not ``workers`` each.
    pool = (concurrent.futures.ThreadPoolExecutor(config.workers, "gijax-loader")
            if len(readers) > 1 and config.workers > 0 else None)

    def stream_factory(r, r_rig):
        return dataset_stream_factory(r, r_rig, config.batch_size, config.seed, mc.surrogate_hw,
                                      mask_augmentation=mc.mask_augmentation,
                                      workers=config.workers, pool=pool,
                                      augment=augment_preset(config.augment))

    if len(readers) == 1:
        make_stream, train_rigs = stream_factory(reader, train_rig), train_rig
    else:
        train_rigs = [r.rig for r in readers]
        make_stream = mixed_stream_factory([stream_factory(r, r.rig) for r in readers],
                                           [len(r) for r in readers], config.seed)
    make_val, val_rig = None, None
    if val:
        val_reader = opened(val, "validation")
        make_val = lambda: validation_batches(val_reader, val_reader.rig,  # noqa: E731
                                              config.batch_size, mc.surrogate_hw,
                                              config.val_batches)
        val_rig = val_reader.rig
    try:
        trainer = Trainer(config, out, train_rigs, make_stream, make_val,
                          rig_name=rig or ", ".join(map(str, datas)),
                          progress=progress, val_rig=val_rig, invocation=invocation,
                          candidates=candidates)
        try:
            history = trainer.fit(stop_at)
        finally:
            trainer.close()
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
    return TrainingResult(trainer.start_step, history)


def _pano_text(reader) -> str:
    from gijax.geometry.panorama_frame import coverage_of

    pano = getattr(reader, "pano", None)
    return "no label panorama" if pano is None else (
        f"{pano.height} x {pano.width} {coverage_of(pano)}")
