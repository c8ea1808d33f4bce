"""Sampling equirectangular maps at sweep coordinates, with the longitude seam handled.

An equirectangular image wraps around in longitude: a coordinate between the last column's
centre (W - 1) and the image edge (W - 0.5) lies between the last and the first column. The
image is padded by one wrapped column on each side before :func:`gijax.sampling.bilinear_sample`
(4-neighbour gather, indices clamped before the gather, explicit validity), so the seam is
interpolated rather than clamped. Rows do not wrap: the pole row and the horizon row are clamped.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from gijax.sampling import bilinear_sample

Array = jax.Array


def pad_wrapped(image: Array) -> Array:
    """(H, W, C) -> (H, W + 2, C): the last column before the first, the first after the last."""
    return jnp.concatenate([image[:, -1:], image, image[:, :1]], axis=1)


def sample_wrapped(image: Array, coords: Array, valid: Array | None = None) -> tuple[Array, Array]:
    """Bilinear sample of an equirectangular ``image`` (H, W, C) at ``coords`` (..., 2) = (u, v).

    Columns wrap (any col in [-0.5, W - 0.5] interpolates across the seam); returns samples
    (..., C), 0 where invalid, and the validity (...).
    """
    shifted = coords + jnp.asarray([1.0, 0.0], coords.dtype)
    return bilinear_sample(pad_wrapped(image), shifted, valid)


def sample_sweep(maps: Array, coords: Array, valid: Array) -> tuple[Array, Array]:
    """Every camera's map at its sweep grid.

    Args:
      maps: (Ncam, H, W, C) per-camera equirectangular maps (features or masks).
      coords: (Ncam, D, h, w, 2) pixel coordinates in those maps (see
        :func:`gijax.sweep.grid.sweep_grid`).
      valid: (Ncam, D, h, w) grid validity.

    Returns:
      samples (Ncam, D, h, w, C), 0 where invalid, and validity (Ncam, D, h, w).
    """
    return jax.vmap(sample_wrapped)(maps, coords, valid)
