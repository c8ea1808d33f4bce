"""Trained models from training run folders, read-only.

A run folder (written by :mod:`gijax.train`) holds ``config.json`` and orbax checkpoints
(:mod:`gijax.store.checkpoints`). Reading one changes nothing in it, since it may be training
right now. Before a checkpoint is restored, its stored parameter shapes are compared with the
ones the folder's configuration builds, so weights of another configuration are reported by
name and shape instead of failing inside the restore (where they would pass for damage).
"""

from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np
from flax import nnx

from gijax.store import checkpoints as ckpt
from gijax.store.configs import read_run_config

WHICH = ("best", "latest")


def _key_name(key) -> str:
    for attr in ("key", "name", "idx"):
        if hasattr(key, attr):
            return str(getattr(key, attr))
    return str(key)


def named_shapes(tree) -> dict[str, tuple]:
    """``{'features.stem.conv.kernel': shape, ...}`` of a parameter pytree: the nnx state of a
    model or the orbax metadata of a stored one (whose leaves end in ``.value`` as well)."""
    out = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        name = ".".join(_key_name(k) for k in path)
        out[name.removesuffix(".value")] = tuple(leaf.shape)
    return out


def check_param_shapes(where: Path, stored: dict, expected: dict, model_name: str) -> None:
    """ConfigurationMismatch naming the first parameter that is missing, unexpected or of
    another shape in a checkpoint (``stored``) than the configuration builds (``expected``)."""
    missing = sorted(set(expected) - set(stored))
    extra = sorted(set(stored) - set(expected))
    if missing or extra:
        raise ckpt.ConfigurationMismatch(
            f"{where}: the checkpoint does not match config.json's model {model_name!r}: "
            f"parameters missing from the checkpoint {missing[:5]}, unexpected in it "
            f"{extra[:5]}")
    for name in sorted(expected):
        if expected[name] != stored[name]:
            raise ckpt.ConfigurationMismatch(
                f"{where}: parameter {name!r} has shape {stored[name]} in the checkpoint but "
                f"config.json's model {model_name!r} expects {expected[name]}")


def _abstract(tree, sharding):
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding),
                        tree)


def load_for_inference(run_dir: str | os.PathLike, which: str = "best"):
    """``(model, model_config, candidates)`` from a run folder alone.

    ``which='best'`` takes the best validated checkpoint when there is one and the newest
    periodic checkpoint otherwise; ``'latest'`` always the newest periodic one. An unreadable
    checkpoint is skipped with a warning for the next older one. The model is in eval mode;
    candidates are the training list, (D,) float64 metres, or for a run that learned its list
    (``learn_candidates``) the list learned up to that checkpoint.
    """
    from gijax.model import create_model

    if which not in WHICH:
        raise ValueError(f"which must be one of {WHICH}; found {which!r}")
    run_dir = Path(run_dir)
    if not run_dir.exists():
        raise FileNotFoundError(f"run folder {run_dir} does not exist")
    if not run_dir.is_dir():
        raise ValueError(f"{run_dir} is a file; a run folder or an inference bundle is a folder")
    run = read_run_config(run_dir)
    model = create_model(run.model, int(run.train.get("seed", 0)))
    _, params, rest = nnx.split(model, nnx.Param, ...)
    dev = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
    expected = named_shapes(params)
    folders = ([ckpt.BEST] if which == "best" else []) + [ckpt.PERIODIC]
    for sub in folders:
        if not (run_dir / sub).is_dir():
            continue
        manager = ckpt.open_manager(run_dir / sub, read_only=True)

        def abstract_for(step, manager=manager):
            stored = ckpt.state_metadata(manager, step)
            check_param_shapes(ckpt.step_dir(manager, step), named_shapes(stored["params"]),
                               expected, run.model.name)
            # Everything besides the model's variables (the optimiser state, the step) is
            # restored as stored: the whole checkpoint is read, so damage anywhere in it is
            # found, and reading needs no knowledge of how the run was optimised.
            return dict(_abstract(stored, dev), params=_abstract(params, dev),
                        rest=_abstract(rest, dev))

        try:
            out = ckpt.restore_newest(manager, abstract_for)
        finally:
            manager.close()
        if out is not None:
            state, meta = out
            from gijax.store.bundles import flatten_variables, require_finite

            require_finite(flatten_variables(nnx.to_pure_dict(state["params"])),
                           run_dir / sub / str(meta.get("step", "")))
            nnx.update(model, state["params"], state["rest"])
            model.eval()
            cand = np.asarray(run.candidates, np.float64)
            if "cand_logits" in state:
                from gijax.candidates.parametrisation import candidates_from_logits

                cand = np.asarray(candidates_from_logits(
                    state["cand_logits"], cand[0], cand[-1]), np.float64)
            return model, run.model, cand
    from gijax.store.bundles import PROVENANCE_FILE, WEIGHTS_FILE

    if (run_dir / PROVENANCE_FILE).is_file():     # what a bundle holds beside its weights
        raise FileNotFoundError(f"bundle {run_dir} lacks its {WEIGHTS_FILE} (a damaged or partly "
                                f"copied bundle)")
    raise FileNotFoundError(f"run folder {run_dir} holds no checkpoint yet (the run has not "
                            f"saved trained weights)")
