"""The network's programs as the cases (and ``benchmarks/bench_whole_vs_stages.py``) compile
them: the eval-mode forward pass of a fresh network, the sweep stage, the forward cut into
its stages, and each stage's training gradient."""

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


def stage_programs(cfg: ModelConfig, seed: int = 0, batch: int = 1,
                   train: bool = False) -> tuple:
    """A fresh network of ``cfg`` (eval mode, or training mode with ``train``: BatchNorm on
    the batch's statistics) on the 3-camera training rig and ``batch`` samples, cut as its
    forward runs: ``(state, (surrogates, masks), whole, stages)``.
    ``whole(state, surrogates, masks)`` is the jittable forward (inverse distance); ``stages``
    lists ``(name, fn)`` for the feature extractor, sweep (grids from the rig included), the
    matching cost (models that have one), cost volume, U-Net and regression, each
    ``fn(state, *outputs of the previous stage)``. A guided refinement is not cut out as a
    stage: it shows in ``whole``."""
    from gijax.model import create_model, model_grids

    rig = network_rig(builtin_rig("paper-train"), cfg)
    model = create_model(cfg, seed=seed)
    if train:
        model.train()
    else:
        model.eval()
    graphdef, state = nnx.split(model)
    sur, masks, cand = network_inputs(cfg, rig.num_cameras, batch)

    def whole(state, sur, masks):
        return nnx.merge(graphdef, state)(sur, masks, model_grids(cfg, rig, cand))["inv_distance"]

    def features(state, sur):
        return nnx.merge(graphdef, state).extract_features(sur)

    def sweep_stage(state, feats):
        return nnx.merge(graphdef, state).sweep(feats, masks, model_grids(cfg, rig, cand))

    def matching(state, sampled, valid):
        # The swept features pass through: the cost volume takes them with this channel.
        model = nnx.merge(graphdef, state)
        return sampled, valid, model.matching(sur, masks, model_grids(cfg, rig, cand))

    def cost_volume(state, sampled, valid, matching=None):
        volume = nnx.merge(graphdef, state).build_cost_volume(sampled, valid, matching)
        # A matching skip reads the cost again at the logits: it passes through.
        return (volume, matching) if cfg.matching_skip else volume

    def unet(state, volume, matching=None):
        return nnx.merge(graphdef, state).unet_logits(volume, matching)

    def regression(state, logits):
        return nnx.merge(graphdef, state).regress(logits, cand)["inv_distance"]

    stages = [("features", features), ("sweep", sweep_stage), ("cost volume", cost_volume),
              ("U-Net", unet), ("regression", regression)]
    if cfg.matching_cost != "none":
        stages.insert(2, ("matching cost", matching))
    return state, (sur, masks), whole, stages


def with_backward(fn, differentiate_inputs: bool):
    """``fn(state, *x)`` -> the same stage's forward and backward as a training step runs them:
    the sum of its floating outputs and its gradient with respect to the network state and,
    with ``differentiate_inputs``, to its floating inputs (what flows back to the stage
    before; the first stage's input, the images, needs none). The sum is returned so that a
    stage whose output no gradient depends on (the matching cost) still runs its forward, as
    it does in a step."""
    import jax
    import jax.numpy as jnp

    def floating(a) -> bool:
        return jnp.issubdtype(jnp.result_type(a), jnp.floating)

    def total(state, *x):
        leaves = jax.tree_util.tree_leaves(fn(state, *x))
        return sum(jnp.sum(leaf) for leaf in leaves if floating(leaf))

    def forward_backward(state, *x):
        inputs = [i + 1 for i, a in enumerate(x) if differentiate_inputs and floating(a)]
        return jax.value_and_grad(total, argnums=(0, *inputs))(state, *x)

    return forward_backward

