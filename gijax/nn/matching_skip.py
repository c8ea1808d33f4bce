"""The matching cost straight to the logits: a zero-initialised 3x3x3 conv added to the U-Net's.

A model with a matching cost (``ModelConfig.matching_cost``) receives it as one channel of the
cost volume, which the U-Net then regularises over 8x coarser stages. A structure one or two
cells wide (a thin pole, a cable, the edge of a near object) can be smoothed away on that
path although the matching cost itself points at the right candidate: the classical
baseline, reading the same ZNCC without a U-Net, finds it. ``matching_skip`` adds a second
path that keeps the cost's resolution: a 3x3x3 conv of the (B, D, h, w, 1) matching cost,
with one output channel and no bias, added to the (B, D, h, w) logits before the
regression.

The conv's output is multiplied by a fixed gain, :data:`SKIP_GAIN`: Adam moves each weight by
about the learning rate per step whatever its gradient's size, the logits of a trained network
span several units where the ZNCC spans [-1, 1], and at a fine-tuning learning rate of 3e-5 an
unscaled kernel would need tens of thousands of steps to pass a cost difference as a logit
difference of one; with the gain, about seven hundred.

Its kernel starts at zero, so a trained network without the skip gains it with its outputs
unchanged (:data:`gijax.nn.presets.GROWN_FIELDS`), and fine-tuning decides how much of the
cost to pass (the gradient with respect to the kernel is the correlation of the logits'
gradient with the cost, non-zero from the first step).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx

from gijax.nn.layers import Conv3D

Array = jax.Array

SKIP_GAIN = 50.0


class MatchingSkip(nnx.Module):
    """(B, D, h, w, 1) matching cost -> (B, D, h, w) logit offsets; zero at initialisation."""

    def __init__(self, rngs: nnx.Rngs, conv3d: str = "auto"):
        self.conv = Conv3D(1, 1, 3, 1, rngs, use_bias=False, lowering=conv3d)
        self.conv.kernel[...] = jnp.zeros(self.conv.kernel.shape, self.conv.kernel.dtype)

    def __call__(self, matching: Array) -> Array:
        if matching.ndim != 5 or matching.shape[-1] != 1:
            raise ValueError(f"MatchingSkip expects the matching cost (B, D, h, w, 1), "
                             f"got {matching.shape}")
        return SKIP_GAIN * self.conv(matching)[..., 0]
