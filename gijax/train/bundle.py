"""Inference bundles: a trained model's weights in one small folder, for shipping.

A run folder holds orbax checkpoints with the optimiser state (three times the weights).
A bundle holds only what inference needs:

* ``config.json``: the run's configuration (same document as the run folder's),
* ``weights.npz``: every model variable (parameters and BatchNorm statistics) as float32,
  keyed by its path in the module tree,
* ``PROVENANCE.json``: the command, data seeds, step and validation metrics that produced it.

``load_model(path)`` accepts a bundle or a run folder, so ``gijax predict``, ``eval``,
``export`` and ``demo`` take either.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

WEIGHTS_FILE = "weights.npz"
PROVENANCE_FILE = "PROVENANCE.json"
_SEP = "/"


def _flatten(pure: dict) -> dict[str, np.ndarray]:
    from flax import traverse_util

    flat = traverse_util.flatten_dict(pure)  # keys are tuples of names and list indices
    return {_SEP.join(str(p) for p in k): np.asarray(v) for k, v in flat.items()}


def save_bundle(model, config_file: str | os.PathLike, out_dir: str | os.PathLike,
                provenance: dict | None = None) -> Path:
    """Write ``model``'s variables, a copy of its run's ``config.json`` and the provenance.

    The folder is assembled under a temporary name and renamed into place, so an interrupted
    call never leaves a bundle that looks complete. One writer at a time: the lock file sits
    beside the bundle (``.NAME.gijax.lock``), since the bundle folder itself is replaced.
    """
    from flax import nnx

    from gijax.io.lock import FolderLock
    from gijax.io.paths import check_output_dir
    from gijax.train.config import CONFIG_FILE

    out_dir = check_output_dir(out_dir, "bundle folder")
    weights = _flatten(nnx.to_pure_dict(nnx.state(model)))
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    with FolderLock(out_dir, "bundle", out_dir.parent / f".{out_dir.name}.gijax.lock"):
        tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
        os.chmod(tmp, 0o755)  # mkdtemp makes it private; a bundle is meant to be shared
        try:
            shutil.copyfile(config_file, tmp / CONFIG_FILE)
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
    from gijax.train.config import CONFIG_FILE
    from gijax.train.trainer import load_for_inference

    run_dir = Path(run_dir)
    model, _, _ = load_for_inference(run_dir, which=which)
    return save_bundle(model, run_dir / CONFIG_FILE, out_dir, provenance)


def is_bundle(path: str | os.PathLike) -> bool:
    return (Path(path) / WEIGHTS_FILE).is_file()


def load_bundle(path: str | os.PathLike):
    """``(model, model_config, candidates)`` from a bundle folder; the model is in eval mode."""
    import jax.numpy as jnp
    from flax import nnx, traverse_util

    from gijax.model import create_model
    from gijax.train.config import load_run_config

    path = Path(path)
    cfg, mc, cand = load_run_config(path)
    model = create_model(mc, cfg.seed)
    state = nnx.state(model)
    expected = _flatten(nnx.to_pure_dict(state))
    import zipfile

    try:
        with np.load(path / WEIGHTS_FILE) as f:
            stored = {k: f[k] for k in f.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path / WEIGHTS_FILE}: unreadable weights ({exc})") from exc
    missing = sorted(set(expected) - set(stored))
    extra = sorted(set(stored) - set(expected))
    if missing or extra:
        raise ValueError(f"{path / WEIGHTS_FILE} does not match model {mc.name!r}: missing "
                         f"{missing[:5]}{'...' if len(missing) > 5 else ''}, unexpected "
                         f"{extra[:5]}{'...' if len(extra) > 5 else ''}")
    for key, ref in expected.items():
        if stored[key].shape != ref.shape:
            raise ValueError(f"{path / WEIGHTS_FILE}: {key} has shape {stored[key].shape}, "
                             f"model {mc.name!r} expects {ref.shape}")
    pure = traverse_util.unflatten_dict(
        {tuple(int(p) if p.isdigit() else p for p in k.split(_SEP)):
         jnp.asarray(v, ref.dtype) for (k, v), ref in
         ((item, expected[item[0]]) for item in stored.items())})
    nnx.replace_by_pure_dict(state, pure)
    nnx.update(model, state)
    model.eval()
    return model, mc, jnp.asarray(cand, jnp.float32)


def load_model(path: str | os.PathLike):
    """``(model, model_config, candidates)`` from a bundle or a training run folder."""
    if is_bundle(path):
        return load_bundle(path)
    from gijax.train.trainer import load_for_inference

    return load_for_inference(path)
