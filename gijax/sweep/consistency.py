"""How much the cameras disagree about what they see at the same 3D points.

Shared by every unlabeled objective that compares cameras at common points (adapting a
candidate list photometrically, refining a calibration from images): the weighted mean
Charbonnier distance of each camera's sample to the weighted mean of all cameras there.
Traceable (jit, vmap, grad in the samples and the weights).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from gijax.numerics import safe_sqrt

Array = jax.Array

# Charbonnier epsilon of the difference, for samples in [0, 1]: below it the distance is
# quadratic (smooth at agreement), above it about linear (robust to outliers).
DISPERSION_EPS = 1e-3


def view_dispersion(samples: Array, weights: Array,
                    eps: float = DISPERSION_EPS) -> tuple[Array, Array]:
    """Disagreement of N cameras' samples at common points.

    Args:
      samples: (N, ..., C) each camera's value (colour, intensity) at each point.
      weights: (N, ...) how much each camera's sample counts there (0 = not seen; a sampled
        mask gives fractions at its edges).
      eps: Charbonnier epsilon.

    Returns ``(dispersion, total)``, both (...): the weighted mean over cameras of
    ``sqrt(|s_i - mean|^2 + eps^2)``, ``mean`` the weighted mean sample, and the total weight
    (a point is compared by at least two cameras' worth of weight where ``total >= 1.5``).
    """
    total = jnp.sum(weights, axis=0)
    mean = jnp.sum(samples * weights[..., None], axis=0) / jnp.maximum(total, 1e-6)[..., None]
    diff = safe_sqrt(jnp.sum((samples - mean) ** 2, axis=-1) + eps**2)
    return jnp.sum(diff * weights, axis=0) / jnp.maximum(total, 1e-6), total


def common_mean_gains(means: Array) -> Array:
    """Per-camera mean colours (..., N, C) -> the gains (..., N, C) that scale each camera's
    channels to the mean over its cameras (axis -2): cameras of another exposure, gain or white
    balance then compare. Means below 1e-3 (a black camera) count as 1e-3."""
    target = jnp.mean(means, axis=-2, keepdims=True)
    return target / jnp.maximum(means, 1e-3)
