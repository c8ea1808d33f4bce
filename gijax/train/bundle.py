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
                figures: dict | None = None) -> Path:
    """Write ``model``'s variables, a copy of its run's ``config.json`` and the provenance.

    ``candidates`` (a run's learned list) replaces the config's training list in the copy.
    ``figures`` maps file names of :data:`FIGURE_PATTERNS` to PNG files copied in.
    ``out_dir`` must be new or a bundle that holds none of ``inputs``
    (:func:`check_replaceable`). The folder is replaced whole and atomically, an interrupted
    call recovered by the next, one writer at a time (:func:`gijax.io.replace.replace_folder`).
    """
    from flax import nnx

    figures = dict(figures or {})
    bad = [name for name in figures if not BUNDLE.names(name) or name in BUNDLE.files]
    if bad:
        raise ValueError(f"bundle figures must be named {' or '.join(FIGURE_PATTERNS)}; "
                         f"found {bad}")
    out_dir = check_replaceable(out_dir, (config_file, *inputs))
    weights = flatten_variables(nnx.to_pure_dict(nnx.state(model)))

    def write(tmp: Path) -> None:
        if candidates is None:
            shutil.copyfile(config_file, tmp / CONFIG_FILE)
        else:
            doc = json.loads(Path(config_file).read_text())
            doc["candidates"] = [float(c) for c in np.asarray(candidates, np.float64)]
            (tmp / CONFIG_FILE).write_text(json.dumps(doc, indent=2) + "\n")
        np.savez(tmp / WEIGHTS_FILE, **{k: v.astype(np.float32) if v.dtype.kind == "f"
                                        else v for k, v in weights.items()})
        (tmp / PROVENANCE_FILE).write_text(json.dumps(provenance or {}, indent=2) + "\n")
        for name, source in figures.items():
            shutil.copyfile(source, tmp / name)

    replace.replace_folder(out_dir, BUNDLE, write, (config_file, *inputs))
    return out_dir


def write_bundle(run_dir: str | os.PathLike, out_dir: str | os.PathLike,
                 provenance: dict | None = None, which: str = "best",
                 figures: dict | None = None) -> Path:
    """The bundle of a training run (its best validated checkpoint by default), with
    ``figures`` as :func:`save_bundle` takes them."""
    from gijax.store.runs import load_for_inference

    run_dir = Path(run_dir)
    model, _, cand = load_for_inference(run_dir, which=which)
    return save_bundle(model, run_dir / CONFIG_FILE, out_dir, provenance, candidates=cand,
                       figures=figures)
