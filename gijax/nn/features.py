"""Shared 2-D feature extractor applied to every camera's surrogate image.

Structure (REFERENCE section 4), C = ``config.feature_channels``, (n1, n2) = ``feature_blocks``:

=============================================  =====================  ==========================
layer                                          output (per image)     parameters (C = 16)
=============================================  =====================  ==========================
input surrogate, RGB in [0, 1]                 Hs x Ws x 3
5x5 conv stride 2 (3 -> C) + BN + LeakyReLU    Hs/2 x Ws/2 x C        1200 + 32
n1 residual blocks (two 3x3 conv + BN each)    Hs/2 x Ws/2 x C        n1 x 2 x (2304 + 32)
3x3 conv stride 2 (C -> C) + BN + LeakyReLU   Hs/4 x Ws/4 x C        2304 + 32
n2 residual blocks                             Hs/4 x Ws/4 x C        n2 x 2 x (2304 + 32)
3x3 conv + BN + LeakyReLU (or spherical conv)  Hs/4 x Ws/4 x C        2304 + 32
=============================================  =====================  ==========================

At paper size (512 x 2048 in, (5, 10) blocks) this gives 128 x 512 x 16 features and 75 984
parameters; the spherical variant has the same count (its 3x3 taps are resampled, not added).
Parameter names follow the layers above; :mod:`gijax.nn.release_weights` maps the release's.
"""

from __future__ import annotations

import jax
from flax import nnx

from gijax.nn.layers import ConvBN, ResidualBlock
from gijax.nn.presets import ModelConfig
from gijax.nn.spherical import SphericalConv

Array = jax.Array


class FeatureExtractor(nnx.Module):
    """(B, Hs, Ws, 3) surrogate images -> (B, Hs/4, Ws/4, C) features, C = feature_channels.

    ``config.features == 'spherical'`` replaces the last conv by :class:`SphericalConv`, built for
    ``config.feature_hw`` over the hemisphere (pole at row 0), so the input must be
    ``config.surrogate_hw``; the plain extractor accepts any size divisible by 4.
    """

    def __init__(self, config: ModelConfig, rngs: nnx.Rngs):
        c = config.feature_channels
        self.spherical = config.features == "spherical"
        self.stem = ConvBN(3, c, 5, 2, rngs, stride=2)
        n1, n2 = config.feature_blocks
        self.blocks1 = nnx.List([ResidualBlock(c, 2, rngs) for _ in range(n1)])
        self.down = ConvBN(c, c, 3, 2, rngs, stride=2)
        self.blocks2 = nnx.List([ResidualBlock(c, 2, rngs) for _ in range(n2)])
        if self.spherical:
            self.last = SphericalConv(c, c, *config.feature_hw, rngs=rngs,
                                      taps=config.spherical_taps)
        else:
            self.last = ConvBN(c, c, 3, 2, rngs)

    def __call__(self, images: Array) -> Array:
        if images.ndim != 4 or images.shape[-1] != 3:
            raise ValueError(f"FeatureExtractor expects (B, H, W, 3) images, got {images.shape}")
        if images.shape[1] % 4 or images.shape[2] % 4:
            raise ValueError(
                f"FeatureExtractor needs image sides divisible by 4, got {images.shape[1:3]}"
            )
        x = self.stem(images)
        for block in self.blocks1:
            x = block(x)
        x = self.down(x)
        for block in self.blocks2:
            x = block(x)
        return self.last(x)
