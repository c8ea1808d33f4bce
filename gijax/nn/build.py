"""Build the config-chosen learned parts of a network from a :class:`ModelConfig`: the
cost-volume builder chosen by ``config.cost_volume`` and the :class:`UNet3D` (the whole network,
and its parameter counts, are :mod:`gijax.model`'s)."""

from __future__ import annotations

from flax import nnx

from gijax.nn.cost_volume import ConcatCostVolume, VarianceCostVolume
from gijax.nn.presets import ModelConfig
from gijax.nn.unet3d import UNet3D


def make_cost_volume(config: ModelConfig, rngs: nnx.Rngs) -> nnx.Module:
    """The config's cost-volume builder, ``feature_channels`` -> ``unet_in`` channels."""
    if config.cost_volume == "concat":
        return ConcatCostVolume(config.num_cameras, config.feature_channels, config.unet_in, rngs,
                                conv3d=config.conv3d, extra_channels=config.cost_extra_channels)
    return VarianceCostVolume(config.feature_channels, config.unet_in, rngs, conv3d=config.conv3d,
                              extra_channels=config.cost_extra_channels)


def make_unet(config: ModelConfig, rngs: nnx.Rngs) -> UNet3D:
    return UNet3D(config.unet_in, config.unet_base, rngs, conv3d=config.conv3d)
