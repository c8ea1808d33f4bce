"""Guided refinement: a light 2-D network that corrects the soft-argmax inverse distance at the
output's resolution from what the cameras see there (gijax's option, ``ModelConfig.refine``;
off in every paper preset).

Lightweight stereo networks regress depth from a coarse cost volume and then refine it with the
reference image, whose edges tell where depth may jump. An omnidirectional rig has no reference
image, so the guide is made from the cameras at the estimated distance: every output pixel's ray
is swept over the candidates at the output's resolution into each camera's *surrogate* image
(RGB, 4x the feature resolution), and at each candidate the colours of the cameras that see the
point give a mean colour and a spread. Weighted by the candidate probabilities, that is the
colour panorama at the estimated distance (sharp, with the scene's edges) and its photometric
inconsistency (high where the estimate is wrong: the cameras see different things there).

=====================================================  =================  ===================
layer                                                  output             parameters (C = 16)
=====================================================  =================  ===================
input: inv x d_min, entropy / log D, guide colour (3),  H x W x 7
colour spread, share of cameras seeing the point
3x3 conv (7 -> C) + BN + LeakyReLU                     H x W x C          1008 + 32
2 residual blocks                                      H x W x C          2 x 2 x (2304 + 32)
3x3 conv (C -> 1) with bias, zero-initialised          H x W x 1          145
=====================================================  =================  ===================

The network's output ``r`` moves the inverse distance by ``r / d_min`` (a unit of ``r`` spans
the whole candidate range); the result is clipped to the candidates' range. Zero-initialised,
the refinement starts as the identity, so a trained model gains it without losing anything.
The probabilities and the coarse estimate enter as constants (``stop_gradient``): the volume
loss keeps training the cost volume, the refinement's own loss (smooth L1 on its output,
:func:`gijax.train.losses.model_loss`) trains only the refinement.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from flax import nnx

from gijax.nn.layers import ConvBN, ResidualBlock

Array = jax.Array

REFINE_CHANNELS = 16
REFINE_BLOCKS = 2
GUIDE_CHANNELS = 7


def colour_guide(colour: Array, seen: Array, prob: Array) -> Array:
    """The guide from the cameras' colours at the candidates.

    Args:
      colour: (B, N, D, H, W, 3) each camera's surrogate colour at each candidate point.
      seen: (B, N, D, H, W) float, 1 where the camera sees the point.
      prob: (B, D, H, W) candidate probabilities.

    Returns:
      (B, H, W, 5): mean colour over the cameras that see the point (3), the colours' standard
      deviation over them (averaged over RGB), and the share of cameras that see it, each the
      expectation over the candidates.
    """
    n = colour.shape[1]
    w = seen[..., None]
    count = jnp.maximum(jnp.sum(w, axis=1), 1.0)                    # (B, D, H, W, 1)
    mean = jnp.sum(w * colour, axis=1) / count                      # (B, D, H, W, 3)
    var = jnp.sum(w * (colour - mean[:, None]) ** 2, axis=1) / count
    spread = jnp.sqrt(jnp.mean(var, axis=-1, keepdims=True) + 1e-12)
    share = jnp.sum(w, axis=1) / n
    per_candidate = jnp.concatenate([mean, spread, share], axis=-1)  # (B, D, H, W, 5)
    return jnp.einsum("bdhw,bdhwc->bhwc", prob, per_candidate)


class GuidedRefinement(nnx.Module):
    """(inverse distance, entropy, guide) at the output's resolution -> refined inverse
    distance (B, H, W), 1/m (see the module docstring)."""

    def __init__(self, num_candidates: int, rngs: nnx.Rngs, channels: int = REFINE_CHANNELS):
        self.log_d = math.log(num_candidates)
        self.stem = ConvBN(GUIDE_CHANNELS, channels, 3, 2, rngs)
        self.blocks = nnx.List([ResidualBlock(channels, 2, rngs) for _ in range(REFINE_BLOCKS)])
        self.head = nnx.Conv(channels, 1, (3, 3), padding=((1, 1), (1, 1)), use_bias=True,
                             kernel_init=nnx.initializers.zeros, rngs=rngs)

    def __call__(self, inv: Array, entropy: Array, guide: Array, inv_range) -> Array:
        lo, hi = inv_range                     # 1 / d_max, 1 / d_min
        x = jnp.concatenate([(inv / hi)[..., None], (entropy / self.log_d)[..., None], guide],
                            axis=-1)
        x = self.stem(x)
        for block in self.blocks:
            x = block(x)
        return jnp.clip(inv + self.head(x)[..., 0] * hi, lo, hi)
