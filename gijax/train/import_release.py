"""Released PyTorch checkpoints in, gijax inference bundles out.

:func:`import_release_weights` reads a state dict of the authors' network (a Lightning
``.ckpt``, a PyTorch ``.pth`` / ``.pt``, or an ``.npz`` of the same names), maps it onto the
gijax model of a preset (:mod:`gijax.nn.release_weights`: names, layouts, BGR -> RGB), and writes
an inference bundle (:mod:`gijax.train.bundle`) that ``gijax predict`` / ``eval`` / ``export``
accept with ``--ckpt``. Reading PyTorch files needs torch (the ``torch`` extra); ``.npz`` files
need nothing more.
"""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from gijax.nn.presets import ModelConfig, get_preset

TORCH_SUFFIXES = (".ckpt", ".pth", ".pt")


def read_state_dict(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The state dict in ``path`` as numpy arrays keyed by the release's names.

    ``.npz``: every array, or only those under ``sd/`` when some are (an archive that also holds
    inputs and outputs). ``.ckpt`` / ``.pth`` / ``.pt``: ``torch.load`` on the CPU; a Lightning
    checkpoint's ``state_dict`` (or a ``model`` / ``state_dict`` entry of a plain dict) is used.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint file")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        try:
            with np.load(path) as f:
                arrays = {k: f[k] for k in f.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise ValueError(f"{path}: unreadable .npz ({exc})") from exc
        if any(k.startswith("sd/") for k in arrays):
            arrays = {k[3:]: v for k, v in arrays.items() if k.startswith("sd/")}
        return arrays
    if suffix not in TORCH_SUFFIXES:
        raise ValueError(f"{path}: unknown checkpoint type {suffix!r}; expected .npz or one of "
                         f"{', '.join(TORCH_SUFFIXES)}")
    try:
        import torch
    except ImportError:
        raise ValueError(f"{path}: reading PyTorch checkpoints needs torch, which is not "
                         "installed; install the extra with pip install 'gijax[torch]', or "
                         "convert the state dict to .npz where torch is available") from None
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a bad file
        raise ValueError(f"{path}: unreadable PyTorch checkpoint ({exc})") from exc
    if isinstance(obj, dict):
        for key in ("state_dict", "model"):
            if isinstance(obj.get(key), dict):
                obj = obj[key]
                break
    if not isinstance(obj, dict):
        raise ValueError(f"{path}: holds a {type(obj).__name__}, not a state dict")
    return {k: v.detach().cpu().numpy() if hasattr(v, "detach") else np.asarray(v)
            for k, v in obj.items()}


def _candidates_for(config: ModelConfig, stored) -> list[float]:
    """The stored candidates, replaced by the preset's exact closed form when they are that
    list rounded to float32 (the release keeps 96 / d in float32)."""
    import jax

    from gijax.candidates import ev_candidates, gi_candidates

    n, lo, hi = config.num_candidates, config.d_min, config.d_max
    with jax.enable_x64(True):  # the closed forms in float64, as the release's lists were written
        gi = np.asarray(gi_candidates(n, lo, hi), np.float64)
        ev = np.asarray(ev_candidates(n, lo, hi), np.float64)
    if stored is None:
        return [float(c) for c in (gi if config.candidates == "gi" else ev)]
    stored = np.asarray(stored, np.float64)
    if stored.shape != (n,):
        raise ValueError(f"the state dict holds {stored.shape[0]} candidates; model "
                         f"{config.name!r} uses {n}")
    for exact in (gi, ev):
        if np.allclose(stored, exact, rtol=1e-5, atol=0):
            return [float(c) for c in exact]
    return [float(c) for c in stored]


def import_release_weights(src: str | os.PathLike, preset: str, out: str | os.PathLike, *,
                           overrides: dict | None = None, input_order: str = "bgr",
                           seed: int = 0) -> Path:
    """Turn a release checkpoint into a gijax inference bundle at ``out``; returns its path.

    ``preset`` names the structure (e.g. 'G16V-released', 'G16VV'); ``overrides`` replace
    ModelConfig fields (sizes, ``spherical_taps``, ...). ``input_order`` is the colour order the
    weights were trained on ('bgr' for the release): the bundle then takes RGB like every gijax
    model. ValueError lists unmapped names, missing entries and shape mismatches.
    """
    from gijax.model import create_model
    from gijax.nn.release_weights import load_state_dict
    from gijax.store.configs import CONFIG_FILE
    from gijax.train.bundle import save_bundle
    from gijax.train.config import TrainConfig, save_run_config

    from gijax.train.bundle import check_replaceable

    src = Path(src)
    check_replaceable(out, (src,))   # before any work: never a folder that is not a bundle
    get_preset(preset)  # an unknown preset name fails here, naming the valid ones
    overrides = dict(overrides or {})
    unknown = set(overrides) - {f.name for f in dataclasses.fields(ModelConfig)}
    if unknown:
        raise ValueError(f"unknown model fields in the overrides: {sorted(unknown)}")
    train_cfg = TrainConfig(preset=preset, model_overrides=overrides, seed=seed)
    config = train_cfg.model_config()
    state_dict = read_state_dict(src)
    model = create_model(config, seed)
    stored = load_state_dict(model, state_dict, input_order=input_order)
    from flax import nnx

    from gijax.store.bundles import flatten_variables, require_finite

    require_finite(flatten_variables(nnx.to_pure_dict(nnx.state(model))), src)
    candidates = _candidates_for(config, stored)
    digest = hashlib.sha256(src.read_bytes()).hexdigest()
    provenance = {
        "source": str(src.resolve()), "source_sha256": digest, "preset": preset,
        "model_overrides": overrides, "input_order_of_source": input_order,
        "converted": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "note": "weights of the authors' released network, converted by gijax import-weights",
    }
    with tempfile.TemporaryDirectory() as tmp:
        save_run_config(tmp, train_cfg, candidates, rig_name="")
        return save_bundle(model, Path(tmp) / CONFIG_FILE, out, provenance, inputs=(src,))
