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

from gijax.io.paths import temporary_folder_beside
from gijax.store.bundles import PROVENANCE_FILE, WEIGHTS_FILE, flatten_variables
from gijax.store.configs import CONFIG_FILE


BUNDLE_FILES = frozenset({CONFIG_FILE, WEIGHTS_FILE, PROVENANCE_FILE})


def _only_bundle_files(folder: Path) -> bool:
    return folder.is_dir() and not folder.is_symlink() and all(
        p.name in BUNDLE_FILES and p.is_file() and not p.is_symlink() for p in folder.iterdir())


def check_replaceable(out_dir: str | os.PathLike, inputs=()) -> Path:
    """``out_dir`` as a Path when a bundle may be written there: a new path, or a bundle folder
    (nothing but ``config.json``, ``weights.npz`` and ``PROVENANCE.json``) that holds none of
    ``inputs`` and is not the working folder or above it; else ValueError, one line, before any
    work is done. gijax replaces only what it wrote."""
    from gijax.io.paths import check_output_dir

    out_dir = check_output_dir(out_dir, "bundle folder")
    if not out_dir.exists() and not out_dir.is_symlink():
        return out_dir
    where = out_dir.resolve()
    if out_dir.is_symlink() or not out_dir.is_dir():
        raise ValueError(f"bundle folder {out_dir}: exists and is not a folder gijax wrote "
                         f"(a link or a file); choose a new path")
    cwd = Path.cwd().resolve()
    if cwd == where or where in cwd.parents:
        raise ValueError(f"bundle folder {out_dir}: is the working folder or holds it; a "
                         f"bundle replaces its folder, so choose a new path")
    for item in inputs:
        item = Path(item).resolve()
        if item == where or where in item.parents:
            raise ValueError(f"bundle folder {out_dir}: holds the input {item}; choose a new "
                             f"path")
    if not _only_bundle_files(out_dir):
        others = sorted(p.name for p in out_dir.iterdir() if p.name not in BUNDLE_FILES)
        raise ValueError(f"bundle folder {out_dir}: exists and is not a bundle (it holds "
                         f"{', '.join(others[:3]) or 'links or folders'}"
                         f"{', ...' if len(others) > 3 else ''}); gijax replaces only a "
                         f"bundle folder, so choose a new path")
    return out_dir


def _recover(out_dir: Path) -> None:
    """Under the bundle's lock: put back a bundle that a killed replacement had moved aside,
    and remove the temporaries such a kill left."""
    aside = sorted(out_dir.parent.glob(f".{out_dir.name}.old-*"))
    if not out_dir.exists() and aside and _only_bundle_files(aside[-1]):
        os.replace(aside[-1], out_dir)
    for tmp in out_dir.parent.glob(f".{out_dir.name}.*"):
        if tmp.is_dir() and not tmp.is_symlink() and _only_bundle_files(tmp):
            shutil.rmtree(tmp)


def save_bundle(model, config_file: str | os.PathLike, out_dir: str | os.PathLike,
                provenance: dict | None = None, candidates=None, inputs=()) -> Path:
    """Write ``model``'s variables, a copy of its run's ``config.json`` and the provenance.

    ``candidates`` (a run's learned list) replaces the config's training list in the copy.
    ``out_dir`` must be new or a bundle that holds none of ``inputs``
    (:func:`check_replaceable`).

    The folder is assembled under a temporary name beside it; an existing bundle is renamed
    aside, the new one renamed into place, and the old one removed, so a reader sees the old
    bundle or the new one and an interrupted call never leaves one that looks complete (the
    next call puts a bundle moved aside back and removes the temporaries). One writer at a
    time: the lock file sits beside the bundle (``.NAME.gijax.lock``), since the bundle folder
    itself is replaced.
    """
    import secrets

    from flax import nnx

    from gijax.io.lock import FolderLock

    out_dir = check_replaceable(out_dir, (config_file, *inputs))
    weights = flatten_variables(nnx.to_pure_dict(nnx.state(model)))
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    with FolderLock(out_dir, "bundle", out_dir.parent / f".{out_dir.name}.gijax.lock"):
        _recover(out_dir)
        # The folder is the unit made atomic (renamed into place when complete), so the files
        # inside it are written plainly; its leftovers hold only bundle file names, which
        # _recover recognises.
        tmp = temporary_folder_beside(out_dir)
        try:
            if candidates is None:
                shutil.copyfile(config_file, tmp / CONFIG_FILE)
            else:
                doc = json.loads(Path(config_file).read_text())
                doc["candidates"] = [float(c) for c in np.asarray(candidates, np.float64)]
                (tmp / CONFIG_FILE).write_text(json.dumps(doc, indent=2) + "\n")
            np.savez(tmp / WEIGHTS_FILE, **{k: v.astype(np.float32) if v.dtype.kind == "f"
                                            else v for k, v in weights.items()})
            (tmp / PROVENANCE_FILE).write_text(json.dumps(provenance or {}, indent=2) + "\n")
            aside = None
            if out_dir.exists():
                aside = out_dir.parent / f".{out_dir.name}.old-{secrets.token_hex(4)}"
                os.replace(out_dir, aside)
            os.replace(tmp, out_dir)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        if aside is not None:
            shutil.rmtree(aside, ignore_errors=True)
    return out_dir


def write_bundle(run_dir: str | os.PathLike, out_dir: str | os.PathLike,
                 provenance: dict | None = None, which: str = "best") -> Path:
    """The bundle of a training run (its best validated checkpoint by default)."""
    from gijax.store.runs import load_for_inference

    run_dir = Path(run_dir)
    model, _, cand = load_for_inference(run_dir, which=which)
    return save_bundle(model, run_dir / CONFIG_FILE, out_dir, provenance, candidates=cand)
