"""Candidate specs: the list a command's ``--candidates`` names, resolved for a model and rig.

One resolver serves ``gijax predict``, ``eval`` and ``export``, the experiments and the
benchmarks. A spec is

* ``train``: the list the model was trained with; a model without one (an untrained preset)
  takes its kind in closed form: EV, or GI at the paper's training baseline (the released lists);
* ``spacing``, ``rig``, ``ev``: a list recomputed for the rig at the model's count and range
  (:data:`gijax.candidates.kinds.RECOMPUTED`): the paper's closed-form GI at the rig's camera
  spacing, gijax's rig-aware GI, or EV;
* anything else: a file of distances in metres (:func:`read_candidate_file`).

Resolved lists are float64 metres, positive and strictly ascending, and (for a network, whose
count is fixed by its weights) exactly as long as the model needs.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from gijax.candidates.closed_form import ev_candidates, gi_candidates
from gijax.candidates.kinds import RECOMPUTED, recomputed_candidates
from gijax.candidates.validation import check_candidates

TRAIN = "train"
METAVAR = "train|spacing|rig|ev|FILE"
KEYWORDS = (TRAIN, "spacing", "rig", "ev")
HELP = ("'train': the training list (from the run folder or bundle; for a model without one, "
        "its preset's kind in closed form: EV, or GI with the paper's baseline); "
        "'spacing': the paper's list recomputed for the rig (Table II), the closed-form GI list "
        "with the rig's camera spacing as the baseline (same count, no retraining needed); "
        "'rig': gijax's extension, rig-aware GI (equal mean pixel steps over the panorama's "
        "rays and the rig's cameras; on the training rig it is close to EV, not to the released "
        "G16); 'ev': evenly spaced in inverse distance; or a file of distances in metres (a "
        "JSON list, or numbers one per line or comma separated)")
LABELS = {"spacing": "the paper's GI at the rig's camera spacing",
          "rig": "rig-aware GI (gijax extension)", "ev": "EV"}


def read_candidate_file(path: str | os.PathLike) -> np.ndarray:
    """Distances (metres, float64) from a candidate file: a JSON list, a JSON object's
    ``candidates`` list, or numbers one per line or comma separated."""
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
    try:
        return np.asarray([float(v) for v in values], np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"candidate file {f}: expected distances in metres ({exc})") from exc


def _read_spec_file(spec: str) -> np.ndarray:
    """The file a ``--candidates`` spec that is no keyword names; when there is no such file,
    one line listing the keywords (a misspelt keyword is the likelier mistake)."""
    if not Path(spec).is_file():
        raise FileNotFoundError(f"--candidates {spec}: not one of the keywords "
                                f"{', '.join(KEYWORDS)}, and no candidate file {spec} exists")
    return read_candidate_file(spec)


def resolve_candidates(spec: str, rig, n: int, d_min: float = 0.5, d_max: float = 100.0, *,
                       train=None, kind: str | None = None,
                       any_count: bool = False) -> tuple[np.ndarray, str]:
    """``(candidates (D,) float64 metres, description)`` for ``--candidates spec``.

    Args:
      spec: see the module docstring.
      rig: the rig the list is for (used by the recomputed specs).
      n, d_min, d_max: the model's candidate count and range (metres).
      train: the model's training list, or None for a model that has none.
      kind: 'ev' or 'gi', the model's candidate kind, for ``train`` without a training list.
      any_count: accept a file of any length (the classical baseline has no fixed count);
        otherwise the list must hold exactly ``n`` distances.
    """
    if spec == TRAIN:
        if train is not None:
            cand, label = np.asarray(train, np.float64), "training list"
        elif kind in ("ev", "gi"):
            fn = ev_candidates if kind == "ev" else gi_candidates
            cand, label = np.asarray(fn(n, d_min, d_max), np.float64), f"{kind.upper()} closed form"
        else:
            raise ValueError("--candidates train: the model has no training list and no "
                             "candidate kind to compute one")
    elif spec in RECOMPUTED:
        cand = np.asarray(recomputed_candidates(spec, n, rig, d_min, d_max), np.float64)
        label = LABELS[spec]
    else:
        cand, label = _read_spec_file(spec), f"from {spec}"
    return check_candidates(cand, f"--candidates {spec}", count=None if any_count else n), label


def model_candidates(spec: str, rig, config, train=None) -> tuple[np.ndarray, str]:
    """:func:`resolve_candidates` for a network configuration: its candidate count, range
    (``num_candidates``, ``d_min``, ``d_max``) and kind (``candidates``) from ``config``."""
    return resolve_candidates(spec, rig, config.num_candidates, config.d_min, config.d_max,
                              train=train, kind=config.candidates)
