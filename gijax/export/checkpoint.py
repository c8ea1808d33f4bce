"""Load a trained model for export, refusing checkpoints that do not match their configuration.

A run folder holds ``config.json`` (model configuration, candidates) and orbax checkpoints.
Before restoring, the stored parameter shapes are compared with the ones the configuration
builds, so a checkpoint written by another configuration is reported by name and shape instead
of failing deep inside the restore (where it would be mistaken for a corrupt file).
"""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np


def _latest_step_dir(run_dir: Path) -> Path | None:
    from gijax.train.checkpoints import BEST, PERIODIC

    for sub in (BEST, PERIODIC):
        folder = run_dir / sub
        if not folder.is_dir():
            continue
        steps = sorted((int(p.name) for p in folder.iterdir()
                        if p.is_dir() and p.name.isdigit() and (p / "state").is_dir()),
                       reverse=True)
        if steps:
            return folder / str(steps[0])
    return None


def _key_name(k) -> str:
    for attr in ("key", "name", "idx"):
        if hasattr(k, attr):
            return str(getattr(k, attr))
    return str(k)


def expected_param_shapes(model) -> dict:
    """{'features.stem.conv.kernel': shape, ...} of a model's trainable parameters."""
    from flax import nnx

    params = nnx.state(model, nnx.Param)
    out = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(params)[0]:
        name = ".".join(_key_name(k) for k in path)
        name = name[:-len(".value")] if name.endswith(".value") else name
        out[name] = tuple(np.shape(leaf))
    return out


def stored_param_shapes(step_dir: Path) -> dict:
    """The same mapping read from an orbax checkpoint's metadata (nothing is loaded)."""
    import orbax.checkpoint as ocp

    meta = ocp.StandardCheckpointer().metadata(step_dir / "state")
    tree = getattr(meta, "item_metadata", meta)
    out = {}
    for leaf in jax.tree_util.tree_leaves(tree):
        name = str(getattr(leaf, "name", ""))
        if not name.startswith("params."):
            continue
        name = name[len("params."):]
        name = name[:-len(".value")] if name.endswith(".value") else name
        out[name] = tuple(leaf.shape)
    return out


def check_checkpoint(run_dir, model) -> Path:
    """The newest checkpoint folder of ``run_dir`` after checking its parameter shapes against
    ``model`` (built from the run's config). FileNotFoundError when there is none (an untrained
    run); ValueError naming the first mismatching parameter otherwise."""
    run_dir = Path(run_dir)
    step_dir = _latest_step_dir(run_dir)
    if step_dir is None:
        raise FileNotFoundError(f"{run_dir}: no checkpoint (the run has not saved trained "
                                f"weights yet); train first, or export --preset NAME for an "
                                f"untrained test model")
    stored = stored_param_shapes(step_dir)
    expected = expected_param_shapes(model)
    cfg_name = model.config.name
    missing = sorted(set(expected) - set(stored))
    extra = sorted(set(stored) - set(expected))
    if missing or extra:
        raise ValueError(f"{step_dir}: the checkpoint does not match config.json's model "
                         f"{cfg_name!r}: parameters missing from the checkpoint {missing[:5]}, "
                         f"unexpected in it {extra[:5]}")
    for name in sorted(expected):
        if expected[name] != stored[name]:
            raise ValueError(f"{step_dir}: parameter {name!r} has shape {stored[name]} in the "
                             f"checkpoint but config.json's model {cfg_name!r} expects "
                             f"{expected[name]}")
    return step_dir


def load_checkpoint(run_dir):
    """(model in eval mode, ModelConfig, candidates (D,) float64 metres) of a run folder, with
    :func:`check_checkpoint` applied before the weights are restored."""
    from gijax.model import create_model
    from gijax.train.config import load_run_config
    from gijax.train.trainer import load_for_inference

    from gijax.train.bundle import is_bundle, load_bundle

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"{run_dir}: no such run folder")
    if is_bundle(run_dir):  # a bundle checks every stored shape against its config itself
        model, mc, cand = load_bundle(run_dir)
        return model, mc, np.asarray(cand, np.float64)
    cfg, mc, _ = load_run_config(run_dir)
    check_checkpoint(run_dir, create_model(mc, cfg.seed))
    model, mc, cand = load_for_inference(run_dir)
    return model, mc, np.asarray(cand, np.float64)
