"""Writing inference bundles: a trained model's weights in one small folder, for shipping.

The bundle format (``config.json``, ``weights.npz``, ``PROVENANCE.json``) and its reader are
:mod:`gijax.store.bundles`; every ``--ckpt`` (predict, eval, export, demo) accepts a bundle
through :func:`gijax.store.load_model`.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Sequence

import numpy as np

from gijax.io import replace
from gijax.io.replace import FolderKind
from gijax.store.bundles import PROVENANCE_FILE, WEIGHTS_FILE, flatten_variables
from gijax.store.configs import CONFIG_FILE


# Figures that describe a bundle (its learning curve, predictions on validation rigs) are
# written with it, in the same atomic replacement, under these names only.
FIGURE_PATTERNS = ("learning_curve.png", "validation_*.png")
BUNDLE = FolderKind("bundle folder", "bundle",
                    frozenset({CONFIG_FILE, WEIGHTS_FILE, PROVENANCE_FILE}),
                    patterns=FIGURE_PATTERNS)


def check_replaceable(out_dir: str | os.PathLike, inputs=()) -> Path:
    """``out_dir`` as a Path when a bundle may be written there: a new path, or a bundle folder
    (nothing but ``config.json``, ``weights.npz`` and ``PROVENANCE.json``) that holds none of
    ``inputs`` and is not the working folder or above it; else ValueError, one line, before any
    work is done (:func:`gijax.io.replace.check_replaceable`)."""
    return replace.check_replaceable(out_dir, BUNDLE, inputs)


def save_bundle(model, config_file: str | os.PathLike, out_dir: str | os.PathLike,
                provenance: dict | None = None, candidates=None, inputs=(),
                figures: dict | None = None, estimate: str | None = None,
                mode_pick: int | None = None) -> Path:
    """Write ``model``'s variables, a copy of its run's ``config.json`` and the provenance.

    ``candidates`` (a run's learned list) replaces the config's training list in the copy,
    ``estimate`` and ``mode_pick`` its network's (:mod:`gijax.nn.regressor`).
    ``figures`` maps file names of :data:`FIGURE_PATTERNS` to PNG files copied in.
    ``out_dir`` must be new or a bundle that holds none of ``inputs``
    (:func:`check_replaceable`). The folder is replaced whole and atomically, an interrupted
    call recovered by the next, one writer at a time (:func:`gijax.io.replace.replace_folder`).
    """
    from flax import nnx

    from gijax.nn.regressor import check_estimate

    if estimate is not None or mode_pick is not None:
        check_estimate(estimate or "mode", 0, mode_pick or 0)
    figures = _checked_figures(figures)
    out_dir = check_replaceable(out_dir, (config_file, *inputs))
    weights = flatten_variables(nnx.to_pure_dict(nnx.state(model)))
    return _write(weights, config_file, out_dir, provenance, candidates, inputs, figures,
                  {"estimate": estimate, "mode_pick": mode_pick})


def _checked_figures(figures: dict | None) -> dict:
    figures = dict(figures or {})
    bad = [name for name in figures if not BUNDLE.names(name) or name in BUNDLE.files]
    if bad:
        raise ValueError(f"bundle figures must be named {' or '.join(FIGURE_PATTERNS)}; "
                         f"found {bad}")
    return figures


def _write(weights: dict, config_file, out_dir: Path, provenance, candidates, inputs,
           figures: dict, reading: dict | None = None) -> Path:
    """The bundle folder of ``weights`` (a ``weights.npz`` key -> array), replaced atomically;
    the fields of ``reading`` that are not None (how the network reads its distances:
    ``estimate``, ``mode_pick``) replace the network configuration's."""
    reading = {k: v for k, v in (reading or {}).items() if v is not None}

    def write(tmp: Path) -> None:
        if candidates is None and not reading:
            shutil.copyfile(config_file, tmp / CONFIG_FILE)
        else:
            doc = json.loads(Path(config_file).read_text())
            if candidates is not None:
                doc["candidates"] = [float(c) for c in np.asarray(candidates, np.float64)]
            doc["model"].update(reading)
            (tmp / CONFIG_FILE).write_text(json.dumps(doc, indent=2) + "\n")
        np.savez(tmp / WEIGHTS_FILE, **{k: v.astype(np.float32) if v.dtype.kind == "f"
                                        else v for k, v in weights.items()})
        (tmp / PROVENANCE_FILE).write_text(json.dumps(provenance or {}, indent=2) + "\n")
        for name, source in figures.items():
            shutil.copyfile(source, tmp / name)

    replace.replace_folder(out_dir, BUNDLE, write, (config_file, *inputs))
    return out_dir


def average_variables(variable_sets: Sequence[dict], where: Sequence = ()) -> dict:
    """The element-wise mean of several sets of network variables (``weights.npz`` key ->
    array), accumulated in float64 and returned in each array's own dtype.

    Averaging the late checkpoints of one run (stochastic weight averaging, Izmailov et al.
    2018) lands nearer the middle of the basin the run wanders in at a high learning rate than
    any one checkpoint does. BatchNorm's running statistics are averaged like the parameters:
    an approximation (they are not recomputed for the averaged parameters). ``where`` names
    the sets in errors; ValueError (one line) when the sets differ in keys, shapes or dtypes,
    or hold a non-float array that differs between them."""
    sets = list(variable_sets)
    names = list(where) or [f"set {i}" for i in range(len(sets))]
    if not sets:
        raise ValueError("averaging needs at least one set of network variables; found none")
    first = sets[0]
    out = {}
    for name, other in zip(names[1:], sets[1:]):
        if set(other) != set(first):
            diff = sorted(set(other) ^ set(first))[0]
            raise ValueError(f"{name}: holds other network variables than {names[0]} (e.g. "
                             f"{diff}): checkpoints of another network cannot be averaged")
    for key, ref in first.items():
        for name, other in zip(names[1:], sets[1:]):
            arr = other[key]
            if arr.shape != ref.shape or arr.dtype != ref.dtype:
                raise ValueError(f"{name}: variable {key} is {arr.dtype} {arr.shape}; "
                                 f"{names[0]} has {ref.dtype} {ref.shape}")
        if ref.dtype.kind == "f":
            out[key] = np.mean([np.asarray(s[key], np.float64) for s in sets],
                               axis=0).astype(ref.dtype)
        else:
            for name, other in zip(names[1:], sets[1:]):
                if not np.array_equal(other[key], ref):
                    raise ValueError(f"{name}: non-float variable {key} differs from "
                                     f"{names[0]}'s; it cannot be averaged")
            out[key] = ref
    return out


def save_averaged_bundle(packs: Sequence, config_file: str | os.PathLike,
                         out_dir: str | os.PathLike, provenance: dict | None = None,
                         figures: dict | None = None) -> Path:
    """A bundle whose weights are the mean of the network variables of ``packs``
    (:class:`gijax.store.packs.Pack`, resume packs of one run; :func:`average_variables`),
    with the ``config.json`` of a bundle or run folder of that run (``config_file``).

    Every pack must hold the network ``config_file`` describes and its candidate list
    (ValueError, one line naming the pack, otherwise); ``out_dir`` as :func:`save_bundle`."""
    from gijax.store.packs import model_variables

    packs = list(packs)
    doc = json.loads(Path(config_file).read_text())
    names = [str(p.folder / str(p.meta.get("state_file", ""))) for p in packs]
    for name, pack in zip(names, packs):
        if pack.meta.get("model_config") != doc.get("model"):
            raise ValueError(f"{name}: its network configuration differs from {config_file}'s "
                             f"'model'; packs of another network cannot go into this bundle")
        if not np.allclose(pack.meta.get("candidates", []), doc.get("candidates", []),
                           rtol=1e-6, atol=0.0):
            raise ValueError(f"{name}: its candidate list differs from {config_file}'s")
    weights = average_variables([model_variables(p) for p in packs], names)
    figures = _checked_figures(figures)
    out_dir = check_replaceable(out_dir, (config_file,))
    return _write(weights, config_file, out_dir, provenance, None, (), figures)


def write_bundle(run_dir: str | os.PathLike, out_dir: str | os.PathLike,
                 provenance: dict | None = None, which: str = "best",
                 figures: dict | None = None, estimate: str | None = None,
                 mode_pick: int | None = None) -> Path:
    """The bundle of a training run (its best validated checkpoint by default), with
    ``figures`` as :func:`save_bundle` takes them; ``estimate`` ('mean' or 'mode') and
    ``mode_pick``, when given, are how the bundle reads its distances, whatever the run's
    configuration says (the weights are the same either way: :mod:`gijax.nn.regressor`)."""
    from gijax.nn.regressor import check_estimate
    from gijax.store.runs import load_for_inference

    if estimate is not None or mode_pick is not None:
        check_estimate(estimate or "mode", 0, mode_pick or 0)   # before the checkpoint is read
    run_dir = Path(run_dir)
    model, _, cand = load_for_inference(run_dir, which=which)
    return save_bundle(model, run_dir / CONFIG_FILE, out_dir, provenance, candidates=cand,
                       figures=figures, estimate=estimate, mode_pick=mode_pick)
