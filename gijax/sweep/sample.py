"""Sampling equirectangular maps at sweep coordinates, with a choice of boundary rule.

Two rules for what a sample near the edge of a map reads (``boundary``):

* ``'zeros'`` (the released network's rule): bilinear with zero padding, every neighbour
  outside the map contributes 0 (PyTorch's ``grid_sample(..., padding_mode='zeros',
  align_corners=False)``, see :func:`gijax.sampling.bilinear_sample_zero_padded`). Nothing
  wraps: a coordinate between the last column's centre (W - 1) and the seam (W - 0.5) blends
  the last column with zeros.
* ``'wrap'``: an equirectangular map wraps around in longitude, so the image is padded by one
  wrapped column on each side before :func:`gijax.sampling.bilinear_sample` and the seam is
  interpolated rather than faded; rows (pole, horizon) are clamped within half a pixel and 0
  beyond.

Both are differentiable in the map and the coordinates and export to plain gathers.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from gijax.sampling import bilinear_sample, bilinear_sample_zero_padded

Array = jax.Array

BOUNDARIES = ("zeros", "wrap")


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


def sample_map(image: Array, coords: Array, boundary: str = "zeros") -> Array:
    """``image`` (H, W, C) at ``coords`` (..., 2) = (col, row) pixels -> (..., C) by ``boundary``."""
    if boundary == "zeros":
        return bilinear_sample_zero_padded(image, coords)
    if boundary == "wrap":
        return sample_wrapped(image, coords)[0]
    raise ValueError(f"sweep boundary must be one of {BOUNDARIES}; found {boundary!r}")


def sample_sweep(maps: Array, coords: Array, boundary: str = "zeros") -> Array:
    """Every camera's map at its sweep grid.

    Args:
      maps: (Ncam, H, W, C) per-camera equirectangular maps (features or masks).
      coords: (Ncam, D, h, w, 2) pixel coordinates in those maps (see
        :func:`gijax.sweep.grid.sweep_grid`).
      boundary: ``'zeros'`` or ``'wrap'`` (module docstring).

    Returns:
      samples (Ncam, D, h, w, C). Grid validity is not applied here: the released concat
      builder reads features wherever the grid points, and the variance builder excludes
      invalid cameras through its mask.
    """
    return jax.vmap(lambda m, c: sample_map(m, c, boundary))(maps, coords)
