"""Inference bundles: a trained model's weights in one small folder, for shipping.

A run folder holds orbax checkpoints with the optimiser state (three times the weights).
A bundle holds only what inference needs:

* ``config.json``: the run's configuration (the same document as a run folder's,
  :mod:`gijax.store.configs`),
* ``weights.npz``: every model variable (parameters and BatchNorm statistics) as float32,
  keyed by its path in the module tree (:func:`flatten_variables`),
* ``PROVENANCE.json``: how it was made (commands, data, step, validation metrics).

Bundles are written by :func:`gijax.train.bundle.save_bundle`; this module reads them.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np

WEIGHTS_FILE = "weights.npz"
PROVENANCE_FILE = "PROVENANCE.json"
_SEP = "/"


def flatten_variables(pure: dict) -> dict[str, np.ndarray]:
    """A pure-dict model state -> ``{'features/stem/conv/kernel': array, ...}`` (the keys of
    ``weights.npz``; list indices become path parts too)."""
    from flax import traverse_util

    flat = traverse_util.flatten_dict(pure)
    return {_SEP.join(str(p) for p in k): np.asarray(v) for k, v in flat.items()}


def require_finite(flat: dict, where) -> None:
    """ValueError naming ``where`` and the first array of ``flat`` (name -> array) that holds
    a NaN or an infinity: such weights would predict nothing but NaN."""
    for key, value in flat.items():
        arr = np.asarray(value)
        if arr.dtype.kind in "fc" and not np.all(np.isfinite(arr)):
            bad = int(arr.size - np.count_nonzero(np.isfinite(arr)))
            raise ValueError(f"{where}: weights {key} hold {bad} non-finite value(s) of "
                             f"{arr.size}; refusing a model that can only predict NaN")


def is_bundle(path: str | os.PathLike) -> bool:
    return (Path(path) / WEIGHTS_FILE).is_file()


def read_provenance(path: str | os.PathLike) -> dict:
    """A bundle's ``PROVENANCE.json`` ({} when it has none or it is not a JSON object: it
    informs, so a damaged one costs only the information)."""
    try:
        doc = json.loads((Path(path) / PROVENANCE_FILE).read_bytes().decode("utf-8"))
    except (OSError, ValueError):     # ValueError: not UTF-8, or not JSON
        return {}
    return doc if isinstance(doc, dict) else {}


def load_bundle(path: str | os.PathLike):
    """``(model, model_config, candidates)`` from a bundle folder; the model is in eval mode,
    candidates are the training list, (D,) float64 metres. ValueError naming the file when the
    weights are unreadable or belong to another network."""
    from gijax.store.configs import read_run_config

    path = Path(path)
    run = read_run_config(path)
    try:
        with np.load(path / WEIGHTS_FILE) as f:
            stored = {k: f[k] for k in f.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path / WEIGHTS_FILE}: unreadable weights ({exc})") from exc
    model = model_with_variables(run.model, int(run.train.get("seed", 0)), stored,
                                 path / WEIGHTS_FILE)
    return model, run.model, np.asarray(run.candidates, np.float64)


def model_with_variables(mc, seed: int, stored: dict, where):
    """The network ``mc`` (a ModelConfig) holding ``stored``, its variables keyed as
    :func:`flatten_variables` keys them, in eval mode. ValueError naming ``where`` when a
    variable is missing, unexpected, of another shape or not finite."""
    import jax.numpy as jnp
    from flax import nnx, traverse_util

    from gijax.model import create_model

    model = create_model(mc, seed)
    state = nnx.state(model)
    expected = flatten_variables(nnx.to_pure_dict(state))
    missing = sorted(set(expected) - set(stored))
    extra = sorted(set(stored) - set(expected))
    if missing or extra:
        raise ValueError(f"{where} does not match model {mc.name!r}: missing "
                         f"{missing[:5]}{'...' if len(missing) > 5 else ''}, unexpected "
                         f"{extra[:5]}{'...' if len(extra) > 5 else ''}")
    for key, ref in expected.items():
        if stored[key].shape != ref.shape:
            raise ValueError(f"{where}: {key} has shape {stored[key].shape}, "
                             f"model {mc.name!r} expects {ref.shape}")
    require_finite(stored, where)
    pure = traverse_util.unflatten_dict(
        {tuple(int(p) if p.isdigit() else p for p in k.split(_SEP)):
         jnp.asarray(v, expected[k].dtype) for k, v in stored.items()})
    nnx.replace_by_pure_dict(state, pure)
    nnx.update(model, state)
    model.eval()
    return model
