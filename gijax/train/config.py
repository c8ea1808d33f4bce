"""Typed training configuration, saved as JSON in every run folder.

A run folder holds ``config.json`` (this file's :class:`TrainConfig`, the resolved
:class:`gijax.nn.presets.ModelConfig` and the training candidates; the document's format is
:mod:`gijax.store.configs`), ``checkpoints/`` (periodic, keep-N), ``best/`` (the best by a
validation metric), ``metrics.jsonl``, TensorBoard event files under ``tb/`` and sample
predictions under ``samples/``.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any, Optional

from gijax.checks import bad_field
from gijax.io.paths import write_text_atomic
from gijax.nn.presets import ModelConfig, get_preset
from gijax.store.configs import CONFIG_FILE, read_run_config, run_config_document

SCHEDULES = ("constant", "cosine", "warmup_cosine", "step")
BATCH_NORM = ("train", "frozen")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """How to train (the network itself is fixed by ``preset`` and ``model_overrides``).

    Attributes:
      preset: model preset name (``gijax.nn.presets.PRESETS``), e.g. 'G16VV-cpu'.
      model_overrides: ModelConfig fields replaced on top of the preset (e.g. smaller sizes).
      lr: peak learning rate of Adam (the paper: 1e-4).
      schedule: 'constant', 'cosine' (decay to ``lr * end_lr_factor`` at ``steps``),
        'warmup_cosine' (linear warm-up over ``warmup_steps``, then cosine) or 'step' (multiply
        by ``decay_factor`` every ``decay_every`` steps).
      clip_norm: clip the global gradient norm to this value (None: no clipping).
      batch_size: global batch (all devices and processes together) per optimiser step.
      grad_accum: split each batch into this many micro-batches whose gradients are averaged
        before the single optimiser update (memory / batch trade-off).
      steps: optimiser steps to train for.
      seed: seeds the model initialisation and the data order.
      bf16: compute the forward/backward pass in bfloat16 (parameters, optimiser and loss stay
        float32); meant for GPUs.
      val_every / ckpt_every / log_every: intervals in steps (0 disables validation /
        periodic checkpoints).
      keep: periodic checkpoints to keep; keep_best: also keep the best one by ``best_metric``
        (a validation metric, lower is better unless ``best_mode='max'``).
      val_batches: at most this many validation batches per validation (0: the whole set).
      workers: loader worker threads; candidates: None for the preset's kind computed for the
        training rig, or a list of distances in metres.
      sample_images: prediction images written per validation.
      augment: training-image augmentation, a ``gijax.data.augment.AUGMENT_PRESETS`` name.
      learn_candidates: make the candidate list a trainable parameter (its logits,
        :mod:`gijax.candidates.parametrisation`; the starting list's ends stay), trained by
        the same loss with its own Adam at ``candidates_lr``; the current list is logged at
        each validation, written to ``candidates.json`` in the run folder and used by eval /
        predict / export of the run.
      calibration_error_deg: each training step gives the network its rig with every camera
        turned by a random rotation of up to this angle (degrees; drawn from the seed and the
        step), so that it learns to tolerate a calibration that is slightly off; the images,
        labels and validation keep the true rig. 0 disables it.
      init_from: a trained model to start from instead of random weights (what ``--ckpt``
        names: a run folder's best checkpoint, a bundle or a bundled model's name): its
        parameters and BatchNorm statistics start the run, with a fresh optimiser, schedule and
        step count (fine-tuning). Its network configuration must be this one's. A run folder
        that already holds a checkpoint resumes from it and does not read ``init_from``.
      pack: a resume pack folder (:mod:`gijax.store.packs`), rewritten at every periodic
        checkpoint with the training state, the data stream's position and the log, small
        enough to commit. A run whose folder holds no newer checkpoint resumes from it (on
        another machine, after the run folder was lost); ``init_from`` is then not read.
      label_free: train without labels: a dict of :class:`gijax.train.unlabeled.LabelFree`
        weights (``photometric``, ``smoothness``, ``teacher``, ``edge_scale``); the step then
        optimises that objective instead of the preset's label loss and never reads the
        batches' labels (validation, when given, still scores against its own labels). None:
        the label loss. Used by ``gijax adapt`` (:mod:`gijax.train.rig_adaptation`).
      batch_norm: 'train' (BatchNorm normalises by each batch's statistics and updates its
        running averages) or 'frozen' (the running statistics it starts with are used and
        kept, as at inference: for fine-tuning on a few frames in small batches).
    """

    preset: str = "G16VV-cpu"
    model_overrides: dict = dataclasses.field(default_factory=dict)
    lr: float = 1e-4
    schedule: str = "constant"
    warmup_steps: int = 0
    end_lr_factor: float = 0.0
    decay_every: int = 10000
    decay_factor: float = 0.5
    clip_norm: Optional[float] = None
    batch_size: int = 2
    grad_accum: int = 1
    steps: int = 1000
    seed: int = 0
    bf16: bool = False
    val_every: int = 500
    ckpt_every: int = 100
    log_every: int = 1
    keep: int = 3
    keep_best: bool = True
    best_metric: str = "mae"
    best_mode: str = "min"
    val_batches: int = 0
    workers: int = 2
    candidates: Optional[list] = None
    sample_images: int = 2
    augment: str = "none"
    learn_candidates: bool = False
    candidates_lr: float = 1e-2
    calibration_error_deg: float = 0.0
    init_from: Optional[str] = None
    pack: Optional[str] = None
    label_free: Optional[dict] = None
    batch_norm: str = "train"

    def __post_init__(self) -> None:
        def fail(field, expected, found):
            raise bad_field("TrainConfig", field, expected, found)

        if self.schedule not in SCHEDULES:
            fail("schedule", f"one of {SCHEDULES}", self.schedule)
        for field in ("batch_size", "grad_accum", "steps", "log_every", "keep"):
            if int(getattr(self, field)) < 1:
                fail(field, "a positive integer", getattr(self, field))
        for field in ("val_every", "ckpt_every", "val_batches", "warmup_steps", "workers"):
            if int(getattr(self, field)) < 0:
                fail(field, "a non-negative integer", getattr(self, field))
        if self.batch_size % self.grad_accum:
            fail("grad_accum", f"a divisor of batch_size {self.batch_size}", self.grad_accum)
        if not self.lr > 0:
            fail("lr", "a positive number", self.lr)
        if not self.candidates_lr > 0:
            fail("candidates_lr", "a positive number", self.candidates_lr)
        if not 0.0 <= self.calibration_error_deg <= 10.0:
            fail("calibration_error_deg", "an angle in [0, 10] degrees", self.calibration_error_deg)
        if self.clip_norm is not None and not self.clip_norm > 0:
            fail("clip_norm", "a positive number or null", self.clip_norm)
        if self.best_mode not in ("min", "max"):
            fail("best_mode", "'min' or 'max'", self.best_mode)
        if self.batch_norm not in BATCH_NORM:
            fail("batch_norm", f"one of {BATCH_NORM}", self.batch_norm)
        if self.label_free is not None:
            self.objective()                      # bad weights fail here
        self.model_config()                       # unknown preset / bad override fails here

    def model_config(self) -> ModelConfig:
        """The preset with ``model_overrides`` applied."""
        base = get_preset(self.preset)
        unknown = set(self.model_overrides) - {f.name for f in dataclasses.fields(ModelConfig)}
        if unknown:
            raise ValueError(f"TrainConfig.model_overrides: unknown ModelConfig fields {sorted(unknown)}")
        over = {k: tuple(v) if isinstance(v, list) else v for k, v in self.model_overrides.items()}
        return dataclasses.replace(base, **over)

    def objective(self):
        """The :class:`gijax.train.unlabeled.LabelFree` objective of ``label_free`` (None
        when the run trains on labels)."""
        if self.label_free is None:
            return None
        from gijax.train.unlabeled import LabelFree

        if not isinstance(self.label_free, dict):
            raise bad_field("TrainConfig", "label_free", "a dict of weights or null",
                            self.label_free)
        return LabelFree.from_dict(self.label_free)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"training config: unknown fields {sorted(unknown)}")
        return cls(**d)


def write_json_atomic(path: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` as indented JSON, atomically (:mod:`gijax.io.paths`)."""
    write_text_atomic(path, json.dumps(obj, indent=2))


def save_run_config(run_dir: str | os.PathLike, config: TrainConfig, candidates, rig_name: str = "") -> None:
    """Write ``RUN/config.json``: training config, resolved model config and candidates (m)."""
    doc = run_config_document(config.to_dict(), config.model_config(), candidates, rig_name)
    write_json_atomic(Path(run_dir) / CONFIG_FILE, doc)


def load_run_config(run_dir: str | os.PathLike) -> tuple[TrainConfig, ModelConfig, list]:
    """Read ``RUN/config.json`` -> (TrainConfig, ModelConfig, candidates in metres)."""
    from gijax.train.unlabeled import stored_objective

    run = read_run_config(run_dir)
    train = dict(run.train)
    if isinstance(train.get("label_free"), dict):
        train["label_free"] = stored_objective(train["label_free"])
    try:
        return TrainConfig.from_dict(train), run.model, run.candidates
    except TypeError as exc:
        raise ValueError(f"{Path(run_dir) / CONFIG_FILE}: unreadable run configuration "
                         f"({exc})") from exc
