"""Build the config-chosen learned parts of a network from a :class:`ModelConfig`: the
cost-volume builder chosen by ``config.cost_volume``, the :class:`UNet3D` and the optional
:class:`MatchingSkip` (the whole network,
and its parameter counts, are :mod:`gijax.model`'s)."""

from __future__ import annotations

from flax import nnx

from gijax.nn.cost_volume import ConcatCostVolume, VarianceCostVolume
from gijax.nn.matching_skip import MatchingSkip
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


def make_matching_skip(config: ModelConfig, rngs: nnx.Rngs) -> MatchingSkip | None:
    """The matching cost's path to the logits when ``config.matching_skip``, else None."""
    return MatchingSkip(rngs, conv3d=config.conv3d) if config.matching_skip else None
