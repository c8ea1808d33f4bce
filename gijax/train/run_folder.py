"""What a run folder (``--out``) may be, which candidates a run in it trains with, and what it
resumes from.

Everything here reads files and raises one ``ValueError`` naming the folder (or pack) and what
differs; nothing is written. The trainer calls these before it builds or restores any state.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Optional

import numpy as np

from gijax.geometry.rig import Rig
from gijax.nn.presets import ModelConfig
from gijax.store.configs import CONFIG_FILE, model_config_from_dict, model_config_to_dict
from gijax.train.config import TrainConfig, load_run_config


def check_run_folder(run_dir: Path) -> None:
    """ValueError, before anything is written, when ``run_dir`` exists and holds files but is
    not a run folder (no ``config.json``): a dataset or any other folder is never trained
    into."""
    from gijax.io.lock import LOCK_FILE

    if not run_dir.is_dir() or (run_dir / CONFIG_FILE).exists():
        return
    others = sorted(p.name for p in run_dir.iterdir() if p.name != LOCK_FILE)
    if others:
        raise ValueError(f"run folder {run_dir}: exists and is not a gijax run folder (it holds "
                         f"{', '.join(others[:3])}{', ...' if len(others) > 3 else ''} and no "
                         f"{CONFIG_FILE}); choose a new --out")


def training_candidates(config: TrainConfig, rig: Optional[Rig]) -> np.ndarray:
    """The candidate list (metres) a new run trains with: explicit, or the preset's kind.

    GI presets train with the closed form at the paper's training baseline (the released G8 /
    G16 lists), exactly as the paper's models did; rig-aware lists are for adapting a trained
    model to another rig (``--candidates rig`` at evaluation and inference).
    """
    mc = config.model_config()
    if config.candidates is not None:
        cand = np.asarray(config.candidates, np.float64)
    else:
        from gijax.candidates.kinds import candidates_for

        kind = "gi-closed" if mc.candidates == "gi" else "ev"
        cand = np.asarray(candidates_for(kind, mc.num_candidates, rig=rig, d_min=mc.d_min,
                                         d_max=mc.d_max), np.float64)
    if cand.shape != (mc.num_candidates,):
        raise ValueError(f"preset {config.preset!r} needs {mc.num_candidates} candidates; "
                         f"found {cand.shape[0] if cand.ndim == 1 else cand.shape}")
    from gijax.candidates.validation import check_candidates

    return check_candidates(cand)


def is_resume(run_dir) -> bool:
    """Whether ``run_dir`` already holds a run (its ``config.json``) that training continues."""
    return (Path(run_dir) / CONFIG_FILE).exists()


def run_candidates(config: TrainConfig, run_dir, rig: Optional[Rig]) -> np.ndarray:
    """The candidate list (metres, float64) of the run in ``run_dir``: the one its
    ``config.json`` records when the folder already holds a run (:func:`check_resumable` says
    whether ``config`` may continue it), else :func:`training_candidates` for a new run.
    Resolved once per run, before the trainer is built."""
    if is_resume(run_dir):
        return np.asarray(load_run_config(run_dir)[2], np.float64)
    return training_candidates(config, rig)


def check_resumable(run_dir: Path, config: TrainConfig, mc: ModelConfig) -> None:
    """ValueError when the run recorded in ``run_dir/config.json`` cannot be continued with
    ``config`` (network ``mc``): another preset, candidate count, network, candidate learning
    setting, objective (labels or label-free weights), BatchNorm mode or candidate list."""
    old_cfg, old_mc, old_cand = load_run_config(run_dir)
    if old_cfg.preset != config.preset:
        raise ValueError(f"run folder {run_dir} was trained with preset "
                         f"{old_cfg.preset!r}; resuming it with preset "
                         f"{config.preset!r} is not possible (use a new --out)")
    if old_mc.num_candidates != mc.num_candidates or len(old_cand) != mc.num_candidates:
        raise ValueError(f"run folder {run_dir} was trained with {len(old_cand)} "
                         f"candidates; this configuration has {mc.num_candidates}")
    # The conv lowering changes how the same weights are computed, not the weights: a run may
    # resume under another one.
    if dataclasses.replace(old_mc, conv3d=mc.conv3d) != mc:
        raise ValueError(f"run folder {run_dir} was trained with another network "
                         f"configuration ({old_mc}); this one is {mc}")
    if old_cfg.learn_candidates != config.learn_candidates:
        say = "learned" if old_cfg.learn_candidates else "fixed"
        raise ValueError(f"run folder {run_dir} was trained with a {say} candidate "
                         f"list; resume it with the same --learn-candidates setting")
    if old_cfg.label_free != config.label_free or old_cfg.batch_norm != config.batch_norm:
        raise ValueError(f"run folder {run_dir} was trained with objective "
                         f"{old_cfg.label_free or 'labels'} and batch_norm "
                         f"{old_cfg.batch_norm!r}; this configuration asks for "
                         f"{config.label_free or 'labels'} and {config.batch_norm!r} (use a new "
                         f"--out)")
    cand = np.asarray(old_cand, np.float64)
    if config.candidates is not None and not np.allclose(config.candidates, cand):
        raise ValueError(f"run folder {run_dir} was trained with candidates "
                         f"{cand.tolist()}; this configuration asks for "
                         f"{list(config.candidates)}")


def check_checkpoint_meta(meta: dict, run_dir: Path, config: TrainConfig,
                          mc: ModelConfig) -> None:
    """ValueError when a checkpoint's (or pack's) metadata belongs to another preset or
    candidate count than this run's."""
    if meta.get("preset") != config.preset:
        raise ValueError(f"checkpoint step {meta.get('step')} in {run_dir} belongs to "
                         f"preset {meta.get('preset')!r}, not {config.preset!r}")
    if len(meta.get("candidates", [])) != mc.num_candidates:
        raise ValueError(f"checkpoint step {meta.get('step')} in {run_dir} has "
                         f"{len(meta.get('candidates', []))} candidates; this configuration "
                         f"has {mc.num_candidates}")


def newer_pack(run_dir: Path, config: TrainConfig, mc: ModelConfig, candidates,
               checkpoint_step: Optional[int]):
    """The run's resume pack (``config.pack``) when it is ahead of the run folder's newest
    checkpoint (at ``checkpoint_step``, None without one) and belongs to this run; else None.
    ValueError when it is ahead but was trained with another network or candidate list."""
    if not config.pack:
        return None
    from gijax.store.packs import read_pack

    pack = read_pack(config.pack)
    if pack is None or (checkpoint_step is not None and pack.step <= checkpoint_step):
        return None
    where = Path(config.pack)
    check_checkpoint_meta(pack.meta, run_dir, config, mc)
    # Read as a config, so that a field added since the pack was written counts at its default
    # (the network it describes is the same one).
    try:
        found = model_config_to_dict(model_config_from_dict(pack.meta.get("model_config", {})))
    except (TypeError, ValueError):
        found = pack.meta.get("model_config", {})
    expected = model_config_to_dict(dataclasses.replace(mc, conv3d="auto"))
    if dict(found, conv3d="auto") != expected:
        diff = sorted(k for k in expected if found.get(k) != expected[k] and k != "conv3d")
        raise ValueError(f"resume pack {where}: its network configuration differs from "
                         f"this run's in {', '.join(diff) or 'its fields'}")
    if not np.allclose(pack.meta["candidates"], candidates, rtol=1e-9, atol=0):
        raise ValueError(f"resume pack {where}: trained with candidates "
                         f"{pack.meta['candidates']}; this run's are "
                         f"{[float(c) for c in candidates]}")
    return pack


def initial_variables(config: TrainConfig, mc: ModelConfig, params, rest):
    """``(params, rest)`` of the model ``config.init_from`` names, checked against this run's
    network ``mc``: same configuration (up to the conv lowering, resolution, panorama coverage,
    input scale and how the distance is read) and variable shapes as ``params`` and ``rest``.
    A part this run adds that starts as the identity (:data:`gijax.nn.presets.GROWN_FIELDS`,
    off in the model it starts from) keeps its initial values from ``params`` / ``rest``."""
    from flax import nnx

    from gijax.nn.presets import GROWN_FIELDS, WEIGHTLESS_FIELDS
    from gijax.store import load_model
    from gijax.store.runs import check_param_shapes, named_shapes

    spec = config.init_from
    model, found, _ = load_model(spec)
    same = {f.name: getattr(mc, f.name) for f in dataclasses.fields(found)
            if f.name in WEIGHTLESS_FIELDS}
    grown = [name for name, off in GROWN_FIELDS.items()
             if getattr(found, name) == off and getattr(mc, name) != off]
    same.update({name: getattr(mc, name) for name in grown})
    if dataclasses.replace(found, **same) != mc:
        diff = {f.name: (getattr(found, f.name), getattr(mc, f.name))
                for f in dataclasses.fields(found) if f.name not in WEIGHTLESS_FIELDS
                and f.name not in grown and getattr(found, f.name) != getattr(mc, f.name)}
        raise ValueError(f"init_from {spec!r}: its network configuration differs from this "
                         f"run's in " + ", ".join(f"{k} (its {a!r}, this run's {b!r})"
                                                  for k, (a, b) in diff.items()))
    model.train()
    _, new_params, new_rest = nnx.split(model, nnx.Param, ...)
    out = []
    for name, new, old in (("parameters", new_params, params), ("variables", new_rest, rest)):
        # The grown parts are modules named after their field (OmniStereoNet.matching_skip).
        kept = {k: v for k, v in named_shapes(old).items() if k.split(".")[0] in grown}
        expected = {k: v for k, v in named_shapes(old).items() if k not in kept}
        check_param_shapes(Path(str(spec)), named_shapes(new), expected,
                           f"{config.preset} ({name})")
        if kept:
            # The model's values written over this run's initial ones; the grown part, absent
            # from the model, keeps its own.
            nnx.replace_by_pure_dict(old, nnx.to_pure_dict(new))
            new = old
        out.append(new)
    return tuple(out)
