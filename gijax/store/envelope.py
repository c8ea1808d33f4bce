"""What a trained model has seen, and how far a rig lies outside it.

A bundle's ``PROVENANCE.json`` lists the datasets it was trained on (``data``: per dataset the
camera count, each camera's field of view, the lens model drawn and, in bundles made since
they were recorded, the camera models and the range of camera spacings). From those records
:func:`training_envelope` takes the ranges; :func:`envelope_note` compares a rig with them and
gives one warning line naming each way the rig is outside (with the trained range beside the
rig's value), so that ``gijax predict`` and ``gijax eval`` say when a model is asked about a
rig unlike anything it learned from. What the records do not hold is not judged.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from gijax.geometry.rig import Rig, pairwise_baselines

# Lens records of the training mixture: "own" is the base rig's calibrated lens.
OWN_LENS = "own"


@dataclasses.dataclass(frozen=True)
class TrainingEnvelope:
    """Ranges over a model's training data (None: not recorded).

    Attributes:
      cameras: (fewest, most) cameras of a training rig.
      fov_deg: (narrowest, widest) field of view of a training camera, degrees.
      spacing_m: (shortest, longest) distance between two cameras of a training rig, metres.
      models: the camera models the training lenses used (gijax model names).
    """

    cameras: tuple[int, int] | None = None
    fov_deg: tuple[float, float] | None = None
    spacing_m: tuple[float, float] | None = None
    models: frozenset[str] | None = None


class _Unreadable(Exception):
    """A record's field in a form this reader does not understand: the field is not judged."""


def _number(value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise _Unreadable()
    return float(value)


def _span(values) -> tuple | None:
    """(min, max) of the recorded numbers (None entries are unrecorded); None when nothing is
    recorded or any entry is not a finite number (a damaged record is not judged)."""
    try:
        values = [_number(v) for v in values if v is not None]
    except _Unreadable:
        return None
    return (min(values), max(values)) if values else None


def _fovs(records) -> tuple | None:
    lists = [r.get("fov_deg") or [] for r in records]
    if any(not isinstance(f, list) for f in lists):
        return None
    return _span(f for fovs in lists for f in fovs)


def _spacing(records) -> tuple | None:
    spacings = [r.get("spacing_m") for r in records]
    if any(not isinstance(s, list) or len(s) != 2 for s in spacings):
        return None
    try:
        pairs = [(_number(s[0]), _number(s[1])) for s in spacings]
    except _Unreadable:
        return None
    return min(p[0] for p in pairs), max(p[1] for p in pairs)


def _models_of(record: dict) -> set[str] | None:
    if isinstance(record.get("models"), list):
        return {str(m) for m in record["models"]}
    lens = record.get("lens")
    if lens is None:
        return None
    if lens != OWN_LENS:
        return {str(lens)}
    from gijax.geometry.layouts import BUILTIN_LAYOUTS, builtin_rig

    if isinstance(record.get("rig"), str) and record["rig"] in BUILTIN_LAYOUTS:          # the rig's own lenses, known by name
        return {c.MODEL for c in builtin_rig(record["rig"]).cameras}
    return None


def training_envelope(provenance: dict) -> TrainingEnvelope | None:
    """The ranges of the ``data`` records of a provenance document, or None without any."""
    data = provenance.get("data", [])
    data = data if isinstance(data, list) else []
    records = [r for r in data if isinstance(r, dict)
               and str(r.get("role", "")).startswith("mix")] or [
        r for r in data if isinstance(r, dict)]
    if not records:
        return None
    cameras = _span(r.get("cameras") for r in records)
    models = [_models_of(r) for r in records]
    return TrainingEnvelope(
        cameras=None if cameras is None else (int(cameras[0]), int(cameras[1])),
        fov_deg=_fovs(records), spacing_m=_spacing(records),
        models=None if any(m is None for m in models) else frozenset().union(*models))


def rig_spacing(rig: Rig) -> tuple[float, float]:
    """(shortest, longest) distance between two cameras of ``rig``, metres."""
    d = pairwise_baselines(rig)
    off = d[~np.eye(len(d), dtype=bool)]
    return float(off.min()), float(off.max())


def outside_envelope(rig: Rig, envelope: TrainingEnvelope, tolerance: float = 0.1) -> list[str]:
    """One phrase per way ``rig`` lies outside ``envelope``: a camera count outside its range,
    a field of view or a camera spacing more than ``tolerance`` (relative) beyond it, a camera
    model it never used."""
    found = []
    if envelope.cameras is not None:
        lo, hi = envelope.cameras
        if not lo <= rig.num_cameras <= hi:
            found.append(f"{rig.num_cameras} cameras (trained on {lo}-{hi})")
    if envelope.fov_deg is not None:
        lo, hi = envelope.fov_deg
        fovs = [math.degrees(float(c.fov)) for c in rig.cameras]
        out = [f"{name} {f:.0f}" for name, f in zip(rig.names, fovs)
               if f < lo * (1 - tolerance) or f > hi * (1 + tolerance)]
        if out:
            found.append(f"fields of view {', '.join(out)} deg (trained on {lo:.0f}-{hi:.0f})")
    if envelope.spacing_m is not None and rig.num_cameras >= 2:
        lo, hi = envelope.spacing_m
        short, long = rig_spacing(rig)
        if short < lo * (1 - tolerance) or long > hi * (1 + tolerance):
            found.append(f"camera spacings {short:.2f}-{long:.2f} m (trained on "
                         f"{lo:.2f}-{hi:.2f} m)")
    if envelope.models is not None:
        unseen = sorted({c.MODEL for c in rig.cameras} - envelope.models)
        if unseen:
            found.append(f"camera model{'s' if len(unseen) > 1 else ''} {', '.join(unseen)} "
                         f"(trained on {', '.join(sorted(envelope.models))})")
    return found


def envelope_note(rig: Rig, provenance: dict, model_name: str) -> str | None:
    """A one-line warning when ``rig`` lies outside what ``provenance`` says the model was
    trained on (None when it lies inside, or nothing is recorded)."""
    envelope = training_envelope(provenance)
    if envelope is None:
        return None
    found = outside_envelope(rig, envelope)
    if not found:
        return None
    return (f"model {model_name!r} never saw a rig like this one: {'; '.join(found)}; expect "
            f"larger errors (its PROVENANCE.json says what it was trained on)")


class OutsideTrainingWarning(UserWarning):
    """A model is run on a rig unlike its training data (filterable by this category)."""


def warn_if_outside_training(rig: Rig, spec, model_name: str) -> bool:
    """Warn (:class:`OutsideTrainingWarning`, one line) when ``rig`` lies outside what the
    model that ``--ckpt spec`` names was trained on; True when it warned."""
    import warnings

    from gijax.store import model_provenance

    note = envelope_note(rig, model_provenance(spec), model_name)
    if note:
        warnings.warn(note, OutsideTrainingWarning, stacklevel=2)
    return note is not None


__all__ = ["OWN_LENS", "OutsideTrainingWarning", "warn_if_outside_training", "TrainingEnvelope", "envelope_note", "outside_envelope", "rig_spacing",
           "training_envelope"]
