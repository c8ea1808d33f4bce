"""Reading trained models: training run folders, inference bundles, and the bundles shipped in
the package by name. Everything that runs a trained model (predict, eval, export, the demo,
the experiments) loads it through :func:`load_model`; :mod:`gijax.train` writes run folders and
bundles and reads its own run folder back through the same modules.

* :mod:`gijax.store.configs`: ``config.json`` (model configuration, training candidates) and
  model configuration files;
* :mod:`gijax.store.checkpoints`: the orbax checkpoint folders of a run;
* :mod:`gijax.store.runs`: a model from a run folder (best or newest checkpoint);
* :mod:`gijax.store.bundles`: a model from an inference bundle;
* :mod:`gijax.store.packs`: a long training's resume packs, and the model in one;
* :mod:`gijax.store.assets`: bundles shipped in ``gijax/assets``, by name.
"""

from __future__ import annotations

import os

from gijax.host_memory import release_freed_memory
from gijax.store.assets import bundled_names, describe_bundled, resolve_model_path
from gijax.store.bundles import is_bundle, load_bundle
from gijax.store.configs import read_preset, read_run_config
from gijax.store.packs import is_pack, load_pack_model
from gijax.store.runs import load_for_inference


def load_model(spec: str | os.PathLike, which: str = "best"):
    """``(model, model_config, candidates)`` from what ``--ckpt`` names: a training run folder
    (``which`` checkpoint: 'best' validated, else newest; or 'latest'), an inference bundle, a
    resume pack (the network at the pack's step; ``which`` does not apply), or the name of a
    bundled model. The model is in eval mode; candidates are its training list,
    (D,) float64 metres. Memory freed while building and restoring goes back to the system
    (:func:`gijax.host_memory.release_freed_memory`)."""
    path = resolve_model_path(spec)
    if is_bundle(path):
        loaded = load_bundle(path)
    elif is_pack(path):
        loaded = load_pack_model(path)
    else:
        loaded = load_for_inference(path, which)
    release_freed_memory()
    return loaded


def model_provenance(spec: str | os.PathLike | None) -> dict:
    """The ``PROVENANCE.json`` of the bundle ``--ckpt spec`` names ({} for a run folder, an
    untrained preset or a bundle without one)."""
    if not spec:
        return {}
    from gijax.store.bundles import read_provenance

    path = resolve_model_path(spec)
    return read_provenance(path) if is_bundle(path) else {}


def model_or_untrained(ckpt: str | os.PathLike | None, preset: str | None, seed: int = 0):
    """``(model, model_config, training candidates or None, label)``: the trained model that
    ``ckpt`` names (see :func:`load_model`), or, without one, a freshly initialised ``preset``
    (random weights from ``seed``: for testing a pipeline, never for results; the label says
    so)."""
    if ckpt:
        model, config, candidates = load_model(ckpt)
        return model, config, candidates, f"{config.name} from {ckpt}"
    from gijax.model import create_model

    config = read_preset(preset)
    model = create_model(config, seed=seed)
    release_freed_memory()
    return (model, config, None,
            f"UNTRAINED {config.name} (random weights, seed {seed})")


__all__ = ["bundled_names", "describe_bundled", "is_bundle", "is_pack", "load_bundle",
           "load_pack_model", "model_provenance",
           "load_for_inference", "load_model", "model_or_untrained", "read_preset", "read_run_config",
           "resolve_model_path"]
