"""The network's programs as the cases (and ``benchmarks/bench_whole_vs_stages.py``) compile
them: the eval-mode forward pass of a fresh network, the sweep stage, and the forward cut into
its stages."""

from __future__ import annotations

import dataclasses

from flax import nnx

from gijax.bench.cost import compile_fn
from gijax.bench.rigs import network_inputs, network_rig
from gijax.geometry.layouts import builtin_rig
from gijax.nn.presets import ModelConfig


def structure(cfg: ModelConfig) -> ModelConfig:
    """Fields that change the computation (the candidate kind and the loss do not)."""
    return dataclasses.replace(cfg, name="", candidates="gi", loss="volume",
                               mask_augmentation=False)


def eval_forward_program(cfg: ModelConfig, rig, batch: int = 1, seed: int = 0):
    """(compiled, args) of the eval-mode forward pass (surrogates -> outputs) of a fresh
    network of ``cfg`` on ``rig`` (already at the network's image size)."""
    from gijax.model import create_model, model_grids

    model = create_model(cfg, seed=seed)
    model.eval()
    graphdef, state = nnx.split(model)
    sur, masks, cand = network_inputs(cfg, rig.num_cameras, batch, seed)

    def forward(state, sur, masks, rig, cand):
        model = nnx.merge(graphdef, state)
        out = model(sur, masks, model_grids(model.config, rig, cand))
        return {k: out[k] for k in ("inv_distance", "distance", "entropy", "valid")}

    args = (state, sur, masks, rig, cand)
    return compile_fn(forward, *args), args


def rig_sweep(cfg, feats, masks, rig, cand):
    """The sweep stage as the forward runs it: grids from the rig, then sampling."""
    from gijax.model import model_grids
    from gijax.sweep.grids import sweep_features

    return sweep_features(feats, masks, model_grids(cfg, rig, cand), cfg.sweep_boundary)


def stage_programs(cfg: ModelConfig, seed: int = 0) -> tuple:
    """A fresh eval-mode network of ``cfg`` on the 3-camera training rig, cut as its forward
    runs: ``(state, surrogates, whole, stages)``. ``whole(state, surrogates, masks)`` is the
    jittable forward (inverse distance); ``stages`` lists ``(name, fn)`` for the feature
    extractor, sweep (grids from the rig included), cost volume, U-Net and regression, each
    ``fn(state, *outputs of the previous stage)``."""
    from gijax.model import create_model, model_grids

    rig = network_rig(builtin_rig("paper-train"), cfg)
    model = create_model(cfg, seed=seed)
    model.eval()
    graphdef, state = nnx.split(model)
    sur, masks, cand = network_inputs(cfg, rig.num_cameras)

    def whole(state, sur, masks):
        return nnx.merge(graphdef, state)(sur, masks, model_grids(cfg, rig, cand))["inv_distance"]

    def features(state, sur):
        return nnx.merge(graphdef, state).extract_features(sur)

    def sweep_stage(state, feats):
        return nnx.merge(graphdef, state).sweep(feats, masks, model_grids(cfg, rig, cand))

    def cost_volume(state, sampled, valid):
        return nnx.merge(graphdef, state).build_cost_volume(sampled, valid)

    def unet(state, volume):
        return nnx.merge(graphdef, state).unet_logits(volume)

    def regression(state, logits):
        return nnx.merge(graphdef, state).regress(logits, cand)["inv_distance"]

    stages = [("features", features), ("sweep", sweep_stage), ("cost volume", cost_volume),
              ("U-Net", unet), ("regression", regression)]
    return state, (sur, masks), whole, stages
