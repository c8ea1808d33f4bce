"""Adapting a trained network to a rig from unlabeled frames: ``gijax adapt`` as a function.

The user has a rig calibration and a few frames of it, no ground truth. :func:`adapt_network`
fine-tunes a trained model (what ``--ckpt`` names) on those frames with the label-free
objective of :mod:`gijax.train.unlabeled` (photometric consistency across the cameras through
the predicted distances, edge-aware smoothness, optionally the classical baseline as a
teacher where it is confident), as an ordinary training run: the :class:`Trainer` of
:mod:`gijax.train.trainer` with ``TrainConfig.label_free`` set, its checkpoints, resume,
``metrics.jsonl`` and progress bar, in a work folder beside the output bundle. The result is an
inference bundle (:mod:`gijax.train.bundle`) whose ``PROVENANCE.json`` says it was adapted,
from which model, on which frames, with which losses.

Frames are read by :func:`gijax.calibrate.frames.read_frames` (frame folders of one image per
camera, or gijax dataset folders, one frame per sample), resized to the model's image size as
every prediction does (:func:`gijax.data.images.fit_images`) and turned into surrogate images
once. Labels that a dataset holds are never read for the loss: the training arrays carry none
(their ``distance`` is NaN and ``valid`` False). A labelled validation dataset may be given to
score the model before and during the adaptation; that score is logged as the ``val`` split
and is not part of the objective.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import NamedTuple, Optional, Sequence

import numpy as np

from gijax.train.unlabeled import LabelFree

TEACHER_FILE = "teacher.npz"


class AdaptationResult(NamedTuple):
    bundle: Path           # the adapted bundle
    work: Path             # the run folder (checkpoints, metrics.jsonl)
    step: int              # optimiser steps done
    history: list          # records logged by this call
    frames: list           # the frames adapted on (folder, or dataset#sample)
    teacher_fraction: Optional[float]   # share of panorama pixels the teacher was trusted on
    before: Optional[dict]  # validation metrics before adapting (with a validation set)


def work_folder(out) -> Path:
    """The run folder of the adaptation that writes bundle ``out``: ``OUT.adapt`` beside it."""
    out = Path(out)
    return out.with_name(out.name + ".adapt")


def train_config_for(spec, mc) -> tuple[str, dict]:
    """``(preset, model_overrides)`` that reproduce the network ``mc`` of the model ``spec``:
    its run's preset and every field that differs from it."""
    from gijax.nn.presets import PRESETS, get_preset
    from gijax.store import read_run_config, resolve_model_path
    from gijax.store.configs import model_config_to_dict

    preset = str(read_run_config(resolve_model_path(spec)).train.get("preset", mc.name))
    if preset not in PRESETS:
        preset = mc.name if mc.name in PRESETS else "G16VV-cpu"
    base = model_config_to_dict(get_preset(preset))
    mine = model_config_to_dict(mc)
    return preset, {k: v for k, v in mine.items() if base.get(k) != v}


def adaptation_rig(frames: Sequence, rig: str | None, coverage: str):
    """``(rig, description, calibrated)``: the rig the frames show. ``rig`` (a name or file:
    ``calibrated``, its images are resized to the model's image size as ``gijax predict``
    resizes them), or without one the first dataset's (at its images' size, used as training
    uses a dataset). A rig file's panorama frame becomes the dataset's when frames come from a
    dataset, else the one ``gijax predict --panorama COVERAGE`` chooses."""
    from gijax.data.format import MANIFEST
    from gijax.data.reader import DatasetReader
    from gijax.geometry.panorama_frame import choose_panorama, with_panorama_rotation

    datasets = [Path(p) for p in frames if (Path(p) / MANIFEST).is_file()]
    if rig is None:
        if not datasets:
            raise ValueError("frame folders need the rig they were taken with: give --rig "
                             "NAME|FILE (a dataset folder brings its own rig)")
        return DatasetReader(datasets[0]).rig, f"the rig of {datasets[0]}", False
    from gijax.io.rigfile import load_rig

    loaded = load_rig(rig)
    if datasets:
        frame = DatasetReader(datasets[0]).rig.panorama_rotation
        return loaded.replace(panorama_rotation=frame), str(rig), True
    choice = choose_panorama(loaded, coverage)
    return with_panorama_rotation(loaded, choice.rotation), str(rig), True


def frame_arrays(frames: Sequence, rig, mc, calibrated: bool = True,
                 max_frames: Optional[int] = None, log=None):
    """Frames -> ``(run_rig, arrays, labels, images, masks)``: the rig at the model's image
    size (``calibrated``: the rig's size times the model's image scale; else the frames' own
    size), the training arrays (``surrogates``, ``masks``, and ``distance`` NaN / ``valid``
    False: no labels), the frames' labels and their images and masks at the model's size
    (uint8 / float32, for the teacher)."""
    import jax.numpy as jnp

    from gijax.calibrate.frames import read_frames
    from gijax.data.images import fit_images
    from gijax.geometry.panorama import Panorama
    from gijax.model import model_panorama

    images, masks, labels = read_frames(frames, rig, max_frames)
    for i, m in enumerate(rig.masks):       # the rig body stays out, whatever the frame says
        if m is not None and np.shape(m) == masks.shape[2:]:
            masks[:, i] *= np.asarray(m, np.float32) > 0
    cam = rig.cameras[0]
    size = ((int(round(cam.height * mc.image_scale)), int(round(cam.width * mc.image_scale)))
            if calibrated else None)
    fitted = [fit_images(rig, im, m, size, log if k == 0 else None)
              for k, (im, m) in enumerate(zip(images, masks))]
    run_rig = fitted[0][0]
    small = np.stack([f[1] for f in fitted])
    small_masks = np.stack([np.asarray(f[2], np.float32) for f in fitted])
    spano = Panorama.hemisphere(*mc.surrogate_hw)
    make = _jitted_surrogates()
    sur, smask = zip(*[make(run_rig, jnp.asarray(im, jnp.float32) / 255.0, jnp.asarray(m), spano)
                       for im, m in zip(small, small_masks)])
    hw = model_panorama(mc).shape
    arrays = {"surrogates": np.stack([np.asarray(s, np.float32) for s in sur]),
              "masks": np.stack([np.asarray(m, np.float32) for m in smask]),
              # No labels: whatever a dataset holds, the objective is never given any.
              "distance": np.full((len(labels), *hw), np.nan, np.float32),
              "valid": np.zeros((len(labels), *hw), bool)}
    return run_rig, arrays, labels, small, small_masks


_SURROGATES: list = []


def _jitted_surrogates():
    """One compiled :func:`gijax.sweep.surrogate.surrogate_images` per process (per shape)."""
    if not _SURROGATES:
        import jax

        from gijax.sweep.surrogate import surrogate_images

        _SURROGATES.append(jax.jit(surrogate_images, static_argnames=("pano",)))
    return _SURROGATES[0]


def teacher_maps(run_rig, images, masks, arrays: dict, mc, preset: str,
                 max_dispersion: float, normalize: bool = True, progress: bool = True) -> dict:
    """The classical baseline's inverse distance on the model's panorama per frame and the
    mask of where it is trusted (:func:`gijax.train.unlabeled.teacher_confidence`, on the
    surrogates as the photometric term compares them: gain-normalised with ``normalize``):
    ``{'teacher_inv' (F, H, W) 1/m (0 where untrusted), 'teacher_mask' (F, H, W)}``."""
    import jax.numpy as jnp
    from tqdm import tqdm

    from gijax.baseline.rtss import rtss_predict_sample
    from gijax.geometry.panorama import Panorama
    from gijax.model import model_panorama, model_rig
    from gijax.train.unlabeled import normalize_gain, teacher_confidence

    pano = model_panorama(mc)
    spano = Panorama.hemisphere(*mc.surrogate_hw)
    invs, trusted = [], []
    for f in tqdm(range(len(images)), desc=f"teacher ({preset})", unit="frame",
                  disable=not progress):
        out = rtss_predict_sample(run_rig, {"images": images[f], "masks": masks[f]}, preset,
                                  pano=pano)
        sur = jnp.asarray(arrays["surrogates"][f:f + 1])
        smask = jnp.asarray(arrays["masks"][f:f + 1])
        if normalize:
            sur = normalize_gain(sur, smask)
        conf = teacher_confidence(sur, smask, model_rig(run_rig),
                                  jnp.asarray(out["inv_distance"])[None],
                                  jnp.asarray(out["valid"])[None], pano, spano,
                                  max_dispersion)[0]
        conf = np.asarray(conf, np.float32)
        invs.append(np.where(conf > 0, out["inv_distance"], 0.0).astype(np.float32))
        trusted.append(conf)
    return {"teacher_inv": np.stack(invs), "teacher_mask": np.stack(trusted)}


def _cached_teacher(work: Path, key: dict) -> Optional[dict]:
    path = work / TEACHER_FILE
    if not path.is_file():
        return None
    try:
        with np.load(path) as z:
            if json.loads(str(z["key"])) != key:
                return None
            return {"teacher_inv": z["teacher_inv"], "teacher_mask": z["teacher_mask"]}
    except (OSError, ValueError, KeyError):
        return None


def _save_teacher(work: Path, key: dict, maps: dict) -> None:
    from gijax.io.paths import atomic_path

    with atomic_path(work / TEACHER_FILE) as tmp:
        np.savez(tmp, key=json.dumps(key), **maps)


def adapt_network(ckpt, frames: Sequence, out, *, rig: str | None = None,
                  objective: LabelFree = LabelFree(), steps: int = 200, lr: float = 2e-5,
                  batch_size: int = 1, seed: int = 0, batch_norm: str = "frozen",
                  ckpt_every: int = 25, keep: int = 2, max_frames: Optional[int] = None,
                  teacher_preset: str = "RS-E32", teacher_max_dispersion: float = 0.02,
                  val: str | os.PathLike | None = None, val_every: int = 0,
                  progress: bool = True, invocation: Optional[dict] = None,
                  stop_at: Optional[int] = None, log=print) -> AdaptationResult:
    """Fine-tune the model ``ckpt`` on unlabeled ``frames`` of a rig; write bundle ``out``.

    Args:
      ckpt: what ``--ckpt`` names (run folder, bundle, bundled model's name).
      frames: frame folders and / or gijax dataset folders (their labels unused).
      out: the bundle to write (new, or a bundle folder that is replaced). The run folder is
        :func:`work_folder` beside it; the same call again resumes there.
      rig: the rig (name or file); default the first dataset's.
      objective: the label-free weights (:class:`gijax.train.unlabeled.LabelFree`).
      steps, lr, batch_size, seed: Adam steps at a constant rate, frames per step, data order.
      batch_norm: 'frozen' (the model's running statistics, as at inference) or 'train'.
      ckpt_every, keep: checkpoint interval and periodic checkpoints kept.
      max_frames: use at most this many frames (the first ones).
      teacher_preset, teacher_max_dispersion: the classical baseline of the teacher term and
        the colour dispersion above which its estimate is not trusted (only with a teacher
        weight).
      val, val_every: a labelled dataset scored before adapting and every ``val_every`` steps
        and at the end (never part of the objective).
      stop_at: end this piece after that many steps in all (the next call continues).
      invocation: what started this piece (logged in ``metrics.jsonl``, kept in provenance).
      log: one-line notes.
    """
    from gijax.io.paths import check_output_dir
    from gijax.model import model_panorama
    from gijax.store import load_model, model_provenance
    from gijax.train.bundle import check_replaceable, write_bundle
    from gijax.train.config import TrainConfig
    from gijax.train.run_folder import check_run_folder
    from gijax.train.sources import array_stream_factory, open_dataset, validation_batches
    from gijax.train.trainer import Trainer

    say = log or (lambda _line: None)
    frames = [str(f) for f in frames]
    if not frames:
        raise ValueError("no frames given")
    for f in frames:
        if not Path(f).is_dir():
            raise FileNotFoundError(f"--frames {f}: not a folder (a frame folder or a gijax "
                                    f"dataset folder)")
    out = check_replaceable(out, frames)
    work = work_folder(out)
    check_output_dir(work, "work folder")
    check_run_folder(work)
    _, mc, train_cand = load_model(ckpt)
    preset, overrides = train_config_for(ckpt, mc)
    the_rig, rig_text, calibrated = adaptation_rig(frames, rig, mc.panorama)
    run_rig, arrays, labels, images, masks = frame_arrays(frames, the_rig, mc, calibrated,
                                                          max_frames, say)
    if batch_size > len(labels):
        raise ValueError(f"--batch {batch_size} is larger than the {len(labels)} frame(s) given")
    say(f"adapting {mc.name} from {ckpt} on {len(labels)} frame(s) of {rig_text} at "
        f"{run_rig.cameras[0].height}x{run_rig.cameras[0].width} px; objective "
        + ", ".join(f"{k} {v:g}" for k, v in objective.to_dict().items()))

    config = TrainConfig(
        preset=preset, model_overrides=overrides, lr=lr, batch_size=batch_size, steps=steps,
        seed=seed, val_every=val_every, ckpt_every=ckpt_every, keep=keep, keep_best=False,
        workers=0, candidates=[float(c) for c in train_cand], init_from=str(ckpt),
        label_free=objective.to_dict(), batch_norm=batch_norm, sample_images=0)
    make_val, val_rig = None, None
    if val:
        val_reader = open_dataset(val, "validation")
        label = getattr(val_reader, "pano", None)
        if label is not None and tuple(label.shape) != tuple(model_panorama(mc).shape):
            raise ValueError(f"validation data {val}: labels are {label.height} x "
                             f"{label.width} panoramas; the model outputs "
                             f"{model_panorama(mc).height} x {model_panorama(mc).width}")
        make_val = lambda: validation_batches(val_reader, val_reader.rig,  # noqa: E731
                                              batch_size, mc.surrogate_hw)
        val_rig = val_reader.rig
    trainer = Trainer(config, work, run_rig, array_stream_factory(arrays, batch_size, seed),
                      make_val, rig_name=rig_text, progress=progress, val_rig=val_rig,
                      invocation=invocation, candidates=train_cand)
    teacher_fraction, before = None, None
    try:
        if objective.teacher:
            key = {"frames": labels, "preset": teacher_preset,
                   "max_dispersion": float(teacher_max_dispersion),
                   "normalize_gain": objective.normalize_gain}
            maps = _cached_teacher(work, key)
            if maps is None:
                maps = teacher_maps(run_rig, images, masks, arrays, mc, teacher_preset,
                                    teacher_max_dispersion, objective.normalize_gain, progress)
                _save_teacher(work, key, maps)
            arrays.update(maps)
            teacher_fraction = float(np.mean(maps["teacher_mask"]))
            say(f"teacher {teacher_preset}: trusted on {100 * teacher_fraction:.1f} % of the "
                f"panorama pixels (valid, colour dispersion <= {teacher_max_dispersion:g})")
        if make_val is not None and trainer.start_step == 0:
            before = trainer.validate(0)
            trainer.log.log({"step": 0, "split": "val", **before})
        history = trainer.fit(stop_at)
    finally:
        trainer.close()
    last_val = next((r for r in reversed(trainer.history) if r.get("split") == "val"), None)
    provenance = {
        "adapted": True, "method": "label-free fine-tuning on unlabeled frames (gijax adapt)",
        "adapted_from": str(ckpt), "adapted_from_provenance": model_provenance(ckpt),
        "frames": labels, "rig": rig_text, "objective": objective.to_dict(),
        "teacher": ({"preset": teacher_preset, "max_dispersion": teacher_max_dispersion,
                     "trusted_fraction": teacher_fraction} if objective.teacher else None),
        "steps": trainer.start_step, "lr": lr, "batch_size": batch_size, "seed": seed,
        "batch_norm": batch_norm, "labels_used_for_loss": False,
        "validation_with_labels": ({"data": str(val), "before": before, "last": last_val}
                                   if val else None),
        "command": (invocation or {}).get("command"), "git": (invocation or {}).get("git"),
    }
    bundle = write_bundle(work, out, provenance, which="latest")
    return AdaptationResult(bundle, work, trainer.start_step, history, labels,
                            teacher_fraction, before)

