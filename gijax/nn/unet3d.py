"""3-D U-Net that regularises the cost volume into per-candidate logits.

The first down stage starts directly on the cost volume (no full-resolution conv before it):
with in/f = 48/96 this is what reproduces the released 36.7 M parameters (and 4.15 M for
16/32, 36.5 M for 16/96, see :mod:`gijax.nn.presets`). Every up step is a trilinear x2 upsample
followed by a 3x3x3 conv, never a 3-D transposed conv, so the network exports to ONNX/TensorRT.

Shape walk-through at paper size (B batch, D = 16 candidates, 80 x 320 cells, in = 48, f = 96):

==========================================================  ============================  =========
step                                                        output                        params
==========================================================  ============================  =========
cost volume                                                 B x 16 x 80 x 320 x 48
down1: conv s2 (48 -> f) + BN + LReLU, 3 residual blocks    B x 8 x 40 x 160 x 96         1.62 M
down2: conv s2 (f -> 2f) + BN + LReLU, 3 residual blocks    B x 4 x 20 x 80 x 192         6.47 M
down3: conv s2 (2f -> 4f) + BN + LReLU, 3 residual blocks   B x 2 x 10 x 40 x 384         25.88 M
up3: upsample x2, conv (4f -> 2f) + BN, + down2, LReLU      B x 4 x 20 x 80 x 192         1.99 M
up2: upsample x2, conv (2f -> f) + BN, + down1, LReLU       B x 8 x 40 x 160 x 96         0.50 M
up1: upsample x2, conv (f -> in) + BN + LReLU (no skip)    B x 16 x 80 x 320 x 48        0.12 M
head: conv (in -> 1) with bias, no norm, squeeze            B x 16 x 80 x 320 (logits)    1 297
==========================================================  ============================  =========

Each stride-2 conv halves the candidate axis as well, so D, h and w must be divisible by 8.
A residual block is two 3x3x3 conv + BN with a skip (:class:`gijax.nn.layers.ResidualBlock`).
"""

from __future__ import annotations

import jax
from flax import nnx

from gijax.nn.layers import ConvBN, ResidualBlock, conv, leaky_relu
from gijax.nn.upsample import upsample2

Array = jax.Array

RESIDUAL_BLOCKS_PER_STAGE = 3


class DownStage(nnx.Module):
    """Stride-2 3x3x3 conv (halves D, h, w) + BN + LeakyReLU, then residual 3-D blocks."""

    def __init__(self, in_ch: int, out_ch: int, rngs: nnx.Rngs, conv3d: str = "auto"):
        self.down = ConvBN(in_ch, out_ch, 3, 3, rngs, stride=2, conv3d=conv3d)
        self.blocks = nnx.List(
            [ResidualBlock(out_ch, 3, rngs, conv3d=conv3d)
             for _ in range(RESIDUAL_BLOCKS_PER_STAGE)]
        )

    def __call__(self, x: Array) -> Array:
        x = self.down(x)
        for block in self.blocks:
            x = block(x)
        return x


class UpStage(nnx.Module):
    """Trilinear x2 upsample, 3x3x3 conv + BN, add the skip (when given), LeakyReLU."""

    def __init__(self, in_ch: int, out_ch: int, rngs: nnx.Rngs, conv3d: str = "auto"):
        self.conv = ConvBN(in_ch, out_ch, 3, 3, rngs, activate=False, conv3d=conv3d)

    def __call__(self, x: Array, skip: Array | None = None) -> Array:
        y = self.conv(upsample2(x, (1, 2, 3)))
        return leaky_relu(y if skip is None else y + skip)


class UNet3D(nnx.Module):
    """(B, D, h, w, in_channels) cost volume -> (B, D, h, w) logits; D, h, w divisible by 8.

    Channels ``base``, ``2 base``, ``4 base`` on the three down stages; every 3-D conv lowers as
    ``conv3d`` (see :class:`gijax.nn.layers.Conv3D`).
    """

    def __init__(self, in_channels: int, base: int, rngs: nnx.Rngs, conv3d: str = "auto"):
        self.in_channels = in_channels
        self.down1 = DownStage(in_channels, base, rngs, conv3d)
        self.down2 = DownStage(base, 2 * base, rngs, conv3d)
        self.down3 = DownStage(2 * base, 4 * base, rngs, conv3d)
        self.up3 = UpStage(4 * base, 2 * base, rngs, conv3d)
        self.up2 = UpStage(2 * base, base, rngs, conv3d)
        self.up1 = UpStage(base, in_channels, rngs, conv3d)
        self.head = conv(in_channels, 1, 3, 3, 1, rngs, use_bias=True, conv3d=conv3d)

    def __call__(self, volume: Array) -> Array:
        if volume.ndim != 5 or volume.shape[-1] != self.in_channels:
            raise ValueError(
                f"UNet3D expects (B, D, h, w, {self.in_channels}), got {volume.shape}"
            )
        d, h, w = volume.shape[1:4]
        if d % 8 or h % 8 or w % 8:
            raise ValueError(
                f"UNet3D halves the candidate and spatial axes 3 times: D, h, w must be "
                f"divisible by 8, got D={d}, h={h}, w={w}"
            )
        s1 = self.down1(volume)
        s2 = self.down2(s1)
        s3 = self.down3(s2)
        x = self.up3(s3, s2)
        x = self.up2(x, s1)
        # The last stage has no skip from the cost volume, as in the release's `out_costs`.
        x = self.up1(x)
        return self.head(x)[..., 0]
