"""Build the learned parts of a network from a :class:`ModelConfig` and count their parameters.

The parts are the shared :class:`FeatureExtractor`, the cost-volume builder chosen by
``config.cost_volume`` and the :class:`UNet3D`; the sweep and the regressor have no parameters.
"""

from __future__ import annotations

import dataclasses
import functools

from flax import nnx

from gijax.nn.cost_volume import ConcatCostVolume, VarianceCostVolume
from gijax.nn.features import FeatureExtractor
from gijax.nn.layers import param_count
from gijax.nn.presets import ModelConfig, get_preset
from gijax.nn.unet3d import UNet3D


def make_cost_volume(config: ModelConfig, rngs: nnx.Rngs) -> nnx.Module:
    """The config's cost-volume builder, ``feature_channels`` -> ``unet_in`` channels."""
    if config.cost_volume == "concat":
        return ConcatCostVolume(config.num_cameras, config.feature_channels, config.unet_in, rngs,
                                conv3d=config.conv3d)
    return VarianceCostVolume(config.feature_channels, config.unet_in, rngs, conv3d=config.conv3d)


def make_unet(config: ModelConfig, rngs: nnx.Rngs) -> UNet3D:
    return UNet3D(config.unet_in, config.unet_base, rngs, conv3d=config.conv3d)


class NetworkParts(nnx.Module):
    """The three learned parts of a config, as attributes ``features``, ``cost``, ``unet``."""

    def __init__(self, config: ModelConfig, rngs: nnx.Rngs):
        self.features = FeatureExtractor(config, rngs)
        self.cost = make_cost_volume(config, rngs)
        self.unet = make_unet(config, rngs)


def count_parameters(config: ModelConfig | str) -> dict[str, int]:
    """Trainable parameter counts {'features', 'cost', 'unet', 'total'} of a config or preset
    name, from abstract shapes only (no memory, no compilation)."""
    if isinstance(config, str):
        config = get_preset(config)
    # Only the layer structure matters: presets differing in candidates, loss or sizes share it.
    structural = dataclasses.replace(
        config, name="", candidates="ev", loss="volume", mask_augmentation=False,
        num_candidates=8, surrogate_hw=(32, 32), cost_hw=(8, 8), output_hw=(16, 16),
        image_scale=1.0, d_min=0.5, d_max=100.0, conv3d="auto",
    )
    return dict(_count(structural))


@functools.lru_cache(maxsize=32)
def _count(config: ModelConfig) -> tuple[tuple[str, int], ...]:
    parts = nnx.eval_shape(lambda: NetworkParts(config, nnx.Rngs(0)))
    counts = {
        "features": param_count(parts.features),
        "cost": param_count(parts.cost),
        "unet": param_count(parts.unet),
    }
    counts["total"] = sum(counts.values())
    return tuple(counts.items())
