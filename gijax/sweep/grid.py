"""Sphere-sweep sampling grids, computed from the rig and the candidate list (pure, jit-able).

For every candidate distance ``d`` and every cell of the cost-volume panorama (the rig's
hemisphere, 80 x 320 at the paper's size, or any panorama oriented by the rig's panorama frame,
:mod:`gijax.geometry.panorama_frame`), the 3D point ``reference + d * ray`` is expressed in
each camera's frame and mapped to that camera's feature-map pixel. A camera's feature map is the
stride-s output of the feature extractor run on its surrogate image (the equirectangular image
of the hemisphere around its optical axis, see :mod:`gijax.sweep.surrogate`); because the
equirectangular pixel map is linear in (longitude, latitude), the feature-map pixel of a
direction is ``direction_to_pixel(feature_pano, direction)``, which equals
``(surrogate pixel + 0.5) * scale - 0.5`` for ``scale = feature width / surrogate width``.

A point is invalid for a camera when it lies outside that camera's hemisphere (behind the
lens plane), outside the lens's valid region (field of view, model domain, image), or at the
camera centre. Nothing is precomputed: the grid follows the rig and the candidates, so a moved
camera or a new candidate list needs no new files.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from gijax.geometry import cameras as cam_lib
from gijax.geometry.panorama import Panorama, direction_to_pixel
from gijax.geometry.panorama_frame import panorama_rays
from gijax.geometry.rig import Rig, map_cameras

Array = jax.Array

# A point closer than this to a camera centre (metres) has no defined direction.
_MIN_RANGE = 1e-6


def sweep_points(rig: Rig, candidates: Array, cost_pano: Panorama) -> Array:
    """(D, h, w, 3) rig-frame points ``reference + d * ray`` of every candidate and cell."""
    rays = panorama_rays(rig, cost_pano)
    cand = jnp.asarray(candidates, rays.dtype)
    return rig.reference + cand[:, None, None, None] * rays[None]


def camera_sweep_grid(cam, rotation: Array, translation: Array, points: Array,
                      feature_pano: Panorama) -> tuple[Array, Array]:
    """One camera: rig-frame points (D, h, w, 3) -> feature-map pixels (D, h, w, 2), validity."""

    def one_candidate(p):
        pc = (p - translation) @ rotation
        coords, in_hemisphere = direction_to_pixel(feature_pano, pc)
        _, in_lens = cam_lib.project(cam, pc)
        far_enough = jnp.sum(pc * pc, axis=-1) > _MIN_RANGE**2
        return coords, in_hemisphere & in_lens & far_enough

    return jax.vmap(one_candidate)(points)


def sweep_grid(rig: Rig, candidates: Array, cost_pano: Panorama,
               feature_pano: Panorama) -> tuple[Array, Array]:
    """Sampling grids of the sphere sweep.

    Args:
      rig: the camera rig (poses camera-to-rig, metres).
      candidates: (D,) candidate distances from ``rig.reference``, metres.
      cost_pano: the cost-volume panorama (h, w cells), oriented by the rig's panorama frame.
      feature_pano: the per-camera feature-map panorama (the surrogate hemisphere at the
        feature extractor's resolution).

    Returns:
      coords: (Ncam, D, h, w, 2) feature-map pixel coordinates (col, row); col lies in
        [-0.5, W - 0.5) and wraps around in longitude (sample with :func:`sample_sweep`).
      valid: (Ncam, D, h, w) bool.
    """
    points = sweep_points(rig, candidates, cost_pano)

    def one(cam, rot, trans, _mask):
        return camera_sweep_grid(cam, rot, trans, points, feature_pano)

    return map_cameras(one, rig)


def rescale_pixels(coords: Array, from_hw: tuple[int, int], to_hw: tuple[int, int]) -> Array:
    """Pixel coordinates (..., 2) = (col, row) on a ``from_hw`` map -> the same points on a
    ``to_hw`` map covering the same field (integer = pixel centre, so ``c + 0.5`` scales)."""
    scale = jnp.asarray([to_hw[1] / from_hw[1], to_hw[0] / from_hw[0]], coords.dtype)
    return (coords + 0.5) * scale - 0.5


def feature_to_surrogate(coords: Array, feature_pano: Panorama,
                         surrogate_pano: Panorama) -> Array:
    """Feature-map pixel coordinates (..., 2) -> surrogate pixel coordinates (same directions)."""
    return rescale_pixels(coords, feature_pano.shape, surrogate_pano.shape)


def pixels_from_normalised(grid: Array, height: int, width: int) -> Array:
    """PyTorch ``grid_sample`` coordinates (..., 2) = (x, y) in [-1, 1] with
    ``align_corners=False`` -> gijax pixel coordinates (col, row) on an ``height`` x ``width``
    map (integer = pixel centre).

    With ``align_corners=False``, -1 and +1 are the outer edges of the first and last pixels,
    so ``col = ((x + 1) W - 1) / 2`` and ``row = ((y + 1) H - 1) / 2``; this is the one place
    where grids made by the authors' code (the release's sweep grids) enter gijax.
    """
    size = jnp.asarray([width, height], grid.dtype)
    return ((grid + 1.0) * size - 1.0) / 2.0


def normalised_from_pixels(coords: Array, height: int, width: int) -> Array:
    """The inverse of :func:`pixels_from_normalised`."""
    size = jnp.asarray([width, height], coords.dtype)
    return (2.0 * coords + 1.0) / size - 1.0
