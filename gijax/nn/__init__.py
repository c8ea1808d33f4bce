"""Flax NNX modules of the stereo network (channels-last): feature extractors (plain and
spherical), cost-volume builders (concat and masked variance), the 3-D U-Net, the matching cost's
skip to the logits, the soft-argmax regressor, and the model presets."""

from gijax.nn.build import make_cost_volume, make_matching_skip, make_unet
from gijax.nn.cost_volume import ConcatCostVolume, VarianceCostVolume, masked_variance
from gijax.nn.features import FeatureExtractor
from gijax.nn.layers import CONV3D_LOWERINGS, Conv3D, param_count
from gijax.nn.matching_skip import MatchingSkip
from gijax.nn.presets import PRESETS, REFERENCE_PARAM_COUNTS, ModelConfig, get_preset
from gijax.nn.regressor import regress
from gijax.nn.spherical import SphericalConv, tangent_offsets
from gijax.nn.unet3d import UNet3D
from gijax.nn.upsample import upsample2

__all__ = [
    "CONV3D_LOWERINGS",
    "PRESETS",
    "REFERENCE_PARAM_COUNTS",
    "ConcatCostVolume",
    "Conv3D",
    "FeatureExtractor",
    "MatchingSkip",
    "ModelConfig",
    "SphericalConv",
    "UNet3D",
    "VarianceCostVolume",
    "get_preset",
    "make_cost_volume",
    "make_matching_skip",
    "make_unet",
    "masked_variance",
    "param_count",
    "regress",
    "tangent_offsets",
    "upsample2",
]
