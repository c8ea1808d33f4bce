"""The whole network: surrogate images -> shared features -> sphere sweep -> cost volume ->
3D U-Net -> soft-argmax in inverse distance.

Shapes for one call (B samples, N cameras, D candidates; paper size in brackets, see
``docs/model.md``):

* surrogates (B, N, Hs, Ws, 3) [512 x 2048] and their masks (B, N, Hs, Ws);
* features (B, N, Hs/4, Ws/4, C) [128 x 512 x 16], one extractor shared by all cameras;
* sweep grids (N, D, h, w, 2) over the rig hemisphere [80 x 320], computed here from the rig and
  the candidates (nothing precomputed), features and masks sampled there;
* cost volume (B, D, h, w, unet_in) [48 concat / 16 variance], U-Net logits (B, D, h, w);
* outputs at (H, W) = 2 (h, w) [160 x 640]: inverse distance (1/m), distance (m), probabilities
  (B, D, H, W), entropy (nats) and ``valid``.

The candidates are an argument, not a weight: a list of the same length can replace the training
list at inference. Variance models accept any number of cameras (at least two).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import Rig
from gijax.nn import (FeatureExtractor, ModelConfig, get_preset, make_cost_volume, make_unet,
                      regress)
from gijax.sweep.grid import feature_to_surrogate, sweep_grid
from gijax.sweep.sample import sample_sweep

Array = jax.Array

# A surrogate pixel counts as seen when its resampled mask exceeds this (masks are bilinear).
MASK_THRESHOLD = 0.5


def check_candidates(config: ModelConfig, candidates) -> None:
    """ValueError unless ``candidates`` is (num_candidates,), and, when its values are known
    (not traced), finite, positive and strictly ascending."""
    shape = tuple(np.shape(candidates))
    if shape != (config.num_candidates,):
        raise ValueError(f"model {config.name!r} needs {config.num_candidates} candidates of shape "
                         f"({config.num_candidates},); found shape {shape}")
    if isinstance(candidates, jax.core.Tracer):
        return
    c = np.asarray(candidates, np.float64)
    if not np.all(np.isfinite(c)) or np.any(c <= 0):
        raise ValueError(f"candidates must be finite positive distances in metres; found {c}")
    if np.any(np.diff(c) <= 0):
        raise ValueError(f"candidates must be strictly ascending distances; found {c}")


def check_inputs(config: ModelConfig, surrogates, masks, rig: Rig, candidates) -> None:
    """ValueError naming the argument, expected and found shape for any mismatch."""
    shape = tuple(np.shape(surrogates))
    hs, ws = config.surrogate_hw
    if len(shape) != 5 or shape[2:] != (hs, ws, 3):
        raise ValueError(f"surrogates must have shape (batch, cameras, {hs}, {ws}, 3) for model "
                         f"{config.name!r}; found {shape}")
    n = shape[1]
    if n != rig.num_cameras:
        raise ValueError(f"the rig has {rig.num_cameras} cameras but {n} surrogate images were "
                         f"given")
    if config.cost_volume == "concat" and n != config.num_cameras:
        raise ValueError(f"model {config.name!r} concatenates exactly {config.num_cameras} cameras;"
                         f" found {n} (variance models accept any number)")
    if n < 2:
        raise ValueError(f"stereo needs at least 2 cameras; found {n}")
    mshape = tuple(np.shape(masks))
    if mshape != shape[:4]:
        raise ValueError(f"masks must have shape {shape[:4]} (batch, cameras, height, width); "
                         f"found {mshape}")
    check_candidates(config, candidates)


class OmniStereoNet(nnx.Module):
    """Omnidirectional stereo from N per-camera surrogate images (see the module docstring)."""

    def __init__(self, config: ModelConfig, rngs: nnx.Rngs):
        self.config = config
        self.features = FeatureExtractor(config, rngs)
        self.cost_volume = make_cost_volume(config, rngs)
        self.unet = make_unet(config, rngs)

    def sweep(self, features: Array, masks: Array, rig: Rig,
              candidates: Array) -> tuple[Array, Array]:
        """Per-camera features (B, N, hf, wf, C) and surrogate masks (B, N, Hs, Ws) sampled at
        the sweep grid: (B, N, D, h, w, C) and per-camera validity (B, N, D, h, w) bool."""
        cfg = self.config
        feature_pano = Panorama.hemisphere(*features.shape[2:4])
        surrogate_pano = Panorama.hemisphere(*masks.shape[2:4])
        coords, grid_ok = sweep_grid(rig, candidates, Panorama.hemisphere(*cfg.cost_hw),
                                     feature_pano)
        coords = coords.astype(features.dtype)
        mask_coords = feature_to_surrogate(coords, feature_pano, surrogate_pano)

        def one(feat, mask):
            sampled, ok = sample_sweep(feat, coords, grid_ok)
            m, _ = sample_sweep(mask[..., None].astype(feat.dtype), mask_coords, grid_ok)
            return sampled, ok & (m[..., 0] > MASK_THRESHOLD)

        return jax.vmap(one)(features, masks)

    def __call__(self, surrogates: Array, masks: Array, rig: Rig, candidates: Array) -> dict:
        """surrogates (B, N, Hs, Ws, 3) in [0, 1], masks (B, N, Hs, Ws), candidates (D,) metres.

        Returns ``inv_distance`` (B, H, W) 1/m, ``distance`` (B, H, W) m, ``prob`` (B, D, H, W),
        ``entropy`` (B, H, W) and ``valid`` (B, H, W) bool: the cell is seen by at least two
        cameras (variance) or by every camera (concat) at every candidate.
        """
        cfg = self.config
        check_inputs(cfg, surrogates, masks, rig, candidates)
        b, n, hs, ws, _ = surrogates.shape
        candidates = jnp.asarray(candidates, surrogates.dtype)
        feats = self.features(surrogates.reshape(b * n, hs, ws, 3))
        feats = feats.reshape(b, n, *feats.shape[1:])
        sampled, cam_valid = self.sweep(feats, masks, rig, candidates)
        volume = self.cost_volume(sampled, cam_valid.astype(sampled.dtype))
        logits = self.unet(volume)
        out = dict(regress(logits, candidates, cfg.output_hw))
        needed = 2 if cfg.cost_volume == "variance" else n
        cell_ok = jnp.all(jnp.sum(cam_valid, axis=1) >= needed, axis=1)  # (B, h, w)
        fy, fx = cfg.output_hw[0] // cfg.cost_hw[0], cfg.output_hw[1] // cfg.cost_hw[1]
        out["valid"] = jnp.repeat(jnp.repeat(cell_ok, fy, axis=1), fx, axis=2)
        return out


# Flax's default initialisers by variable name: conv / linear kernels are LeCun-normal
# (truncated at two standard deviations, rescaled to keep the variance 1 / fan_in), biases
# and BatchNorm shifts and running means 0, BatchNorm scales and running variances 1.
_TRUNCATED_NORMAL_STD = 0.87962566103423978  # std of a unit normal truncated to [-2, 2]
_CONSTANT_INIT = {"bias": 0.0, "mean": 0.0, "scale": 1.0, "var": 1.0}


def _lecun_normal(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    z = rng.standard_normal(shape)
    bad = np.abs(z) > 2.0
    while bad.any():
        z[bad] = rng.standard_normal(int(bad.sum()))
        bad = np.abs(z) > 2.0
    fan_in = int(np.prod(shape[:-1]))
    return z * (np.sqrt(1.0 / fan_in) / _TRUNCATED_NORMAL_STD)


def numpy_initialised(config: ModelConfig, seed: int = 0) -> OmniStereoNet | None:
    """The model with flax's default initial distributions drawn by numpy, or None when it
    holds a variable these defaults do not cover.

    Why: XLA compiles one initialiser program per distinct weight shape (about half a CPU
    second each here), which makes building a paper-size network take a minute; building it
    abstractly and filling the arrays with numpy takes well under a second.
    """
    abstract = nnx.eval_shape(lambda: OmniStereoNet(config, nnx.Rngs(seed)))
    graphdef, state = nnx.split(abstract)
    rng = np.random.default_rng(seed)
    known = True

    def fill(path, leaf):
        nonlocal known
        names = [getattr(k, "key", getattr(k, "name", None)) for k in path]
        name = names[-2] if names and names[-1] == "value" else names[-1]
        if name == "kernel":
            return jnp.asarray(_lecun_normal(rng, tuple(leaf.shape)), leaf.dtype)
        if name in _CONSTANT_INIT:
            return jnp.full(leaf.shape, _CONSTANT_INIT[name], leaf.dtype)
        known = False
        return leaf

    state = jax.tree_util.tree_map_with_path(fill, state)
    if not known:
        return None
    return nnx.merge(graphdef, state)


def create_model(name_or_config: str | ModelConfig, seed: int = 0) -> OmniStereoNet:
    """A freshly initialised :class:`OmniStereoNet` from a preset name (e.g. 'G16VV-cpu') or a
    :class:`~gijax.nn.presets.ModelConfig`; ``seed`` fixes the initial weights.

    The weights follow flax's default initial distributions (see :func:`numpy_initialised`);
    a module with other variables is initialised by its own initialisers.
    """
    config = get_preset(name_or_config) if isinstance(name_or_config, str) else name_or_config
    if not isinstance(config, ModelConfig):
        raise ValueError(f"expected a preset name or a ModelConfig; found "
                         f"{type(name_or_config).__name__}")
    model = numpy_initialised(config, seed)
    return model if model is not None else OmniStereoNet(config, nnx.Rngs(seed))
