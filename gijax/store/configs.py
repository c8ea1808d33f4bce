"""Model and run configurations on disk: the JSON documents every trained model carries.

``config.json`` sits in every training run folder and every inference bundle::

    {"train": {TrainConfig fields}, "model": {ModelConfig fields},
     "candidates": [training candidates, metres], "rig": "what the run trained on"}

The store reads the model half and the candidates (all inference needs) and hands the training
half back as a plain dict: interpreting it is the trainer's business (:mod:`gijax.train.config`).
A model configuration file (``--preset FILE.json``) holds the ModelConfig fields alone.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path
from typing import NamedTuple

from gijax.io.text import one_line, read_text
from gijax.nn.presets import ModelConfig, get_preset

CONFIG_FILE = "config.json"
# A run folder's log (one JSON record per line), written by gijax.train.logbook and carried
# by resume packs.
METRICS_FILE = "metrics.jsonl"


def model_config_to_dict(config: ModelConfig) -> dict:
    """JSON-ready fields (tuples become lists)."""
    return {k: list(v) if isinstance(v, tuple) else v
            for k, v in dataclasses.asdict(config).items()}


def model_config_from_dict(fields: dict) -> ModelConfig:
    """The inverse of :func:`model_config_to_dict`; fields a document lacks take their defaults
    (documents written before a field existed), unknown fields are a TypeError."""
    return ModelConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()})


def read_preset(spec: str) -> ModelConfig:
    """A preset name (``G16VV-cpu``) or a JSON file of ModelConfig fields -> ModelConfig."""
    if not spec.lower().endswith(".json"):
        return get_preset(spec)
    path = Path(spec)
    if not path.is_file():
        raise FileNotFoundError(f"{spec}: no such model configuration file")
    try:
        return model_config_from_dict(json.loads(read_text(path, "model configuration")))
    except (ValueError, TypeError, AttributeError, OverflowError) as exc:
        # ValueError covers bad JSON and ModelConfig's own checks, which do not name the file.
        raise ValueError(f"{spec}: not a JSON object of ModelConfig fields "
                         f"({one_line(exc)})") from None


class RunConfig(NamedTuple):
    """``config.json`` of a run folder or bundle, as read by :func:`read_run_config`."""

    train: dict          # TrainConfig fields, uninterpreted
    model: ModelConfig
    candidates: list     # training candidates, metres
    rig: str


def run_config_document(train: dict, model: ModelConfig, candidates, rig: str = "") -> dict:
    """The ``config.json`` document (see the module docstring)."""
    return {"train": dict(train), "model": model_config_to_dict(model),
            "candidates": [float(c) for c in candidates], "rig": rig}


def read_run_config(folder: str | os.PathLike) -> RunConfig:
    """``FOLDER/config.json`` of a run folder or bundle."""
    path = Path(folder) / CONFIG_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no run configuration (is {folder} a training run "
                                f"folder or a bundle?)")
    try:
        doc = json.loads(read_text(path, "run configuration"))
        run = RunConfig(dict(doc["train"]), model_config_from_dict(doc["model"]),
                        list(doc["candidates"]), str(doc.get("rig", "")))
    except (ValueError, KeyError, TypeError, AttributeError, OverflowError) as exc:
        # ValueError covers bad JSON and ModelConfig's own checks, which do not name the file.
        raise ValueError(f"{path}: unreadable run configuration ({type(exc).__name__}: "
                         f"{one_line(exc)})") from None
    bad = [c for c in run.candidates if isinstance(c, bool) or not isinstance(c, (int, float))
           or not math.isfinite(c) or c <= 0]
    if not run.candidates or bad:
        raise ValueError(f"{path}: field 'candidates' must be a non-empty list of finite "
                         f"positive distances in metres; found {run.candidates!r}")
    return run
