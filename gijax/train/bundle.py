"""Writing inference bundles: a trained model's weights in one small folder, for shipping.

The bundle format (``config.json``, ``weights.npz``, ``PROVENANCE.json``) and its reader are
:mod:`gijax.store.bundles`; every ``--ckpt`` (predict, eval, export, demo) accepts a bundle
through :func:`gijax.store.load_model`.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from gijax.store.bundles import PROVENANCE_FILE, WEIGHTS_FILE, flatten_variables
from gijax.store.configs import CONFIG_FILE


def save_bundle(model, config_file: str | os.PathLike, out_dir: str | os.PathLike,
                provenance: dict | None = None, candidates=None) -> Path:
    """Write ``model``'s variables, a copy of its run's ``config.json`` and the provenance.

    ``candidates`` (a run's learned list) replaces the config's training list in the copy.

    The folder is assembled under a temporary name and renamed into place, so an interrupted
    call never leaves a bundle that looks complete. One writer at a time: the lock file sits
    beside the bundle (``.NAME.gijax.lock``), since the bundle folder itself is replaced.
    """
    from flax import nnx

    from gijax.io.lock import FolderLock
    from gijax.io.paths import check_output_dir

    out_dir = check_output_dir(out_dir, "bundle folder")
    weights = flatten_variables(nnx.to_pure_dict(nnx.state(model)))
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    with FolderLock(out_dir, "bundle", out_dir.parent / f".{out_dir.name}.gijax.lock"):
        tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
        os.chmod(tmp, 0o755)  # mkdtemp makes it private; a bundle is meant to be shared
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
            if out_dir.exists():
                shutil.rmtree(out_dir)
            os.replace(tmp, out_dir)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return out_dir


def write_bundle(run_dir: str | os.PathLike, out_dir: str | os.PathLike,
                 provenance: dict | None = None, which: str = "best") -> Path:
    """The bundle of a training run (its best validated checkpoint by default)."""
    from gijax.store.runs import load_for_inference

    run_dir = Path(run_dir)
    model, _, cand = load_for_inference(run_dir, which=which)
    return save_bundle(model, run_dir / CONFIG_FILE, out_dir, provenance, candidates=cand)
