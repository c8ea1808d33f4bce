"""Surrogate images: each raw fisheye resampled to the hemisphere in front of its lens.

The network consumes, per camera, an equirectangular image of the hemisphere around that
camera's optical axis (latitude -90..0 deg with the pole on the axis, longitude -180..180 deg;
512 x 2048 in the paper). Pixels the lens does not see, or that its mask marks invalid, are 0.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from gijax.geometry import cameras as cam_lib
from gijax.geometry.panorama import Panorama, ray_grid
from gijax.geometry.rig import Rig, map_cameras
from gijax.sampling import bilinear_sample

Array = jax.Array


def surrogate_grid(cam, pano: Panorama) -> tuple[Array, Array]:
    """(H, W, 2) fisheye pixel coordinates of every surrogate pixel, and their validity."""
    rays = ray_grid(pano)
    return cam_lib.project(cam, rays)


def surrogate_image(cam, image: Array, mask: Array, pano: Panorama) -> tuple[Array, Array]:
    """One camera: image (h, w, C) float and mask (h, w) -> surrogate (H, W, C) and mask (H, W).

    The returned mask is the bilinearly resampled validity mask times the projection validity,
    so it is fractional near mask edges; use ``> 0.5`` (or ``> 0``) for a binary decision.
    """
    px, ok = surrogate_grid(cam, pano)
    img, ok_img = bilinear_sample(image, px, ok)
    m, _ = bilinear_sample(mask[..., None].astype(image.dtype), px, ok)
    m = m[..., 0] * ok_img
    return img * (m > 0.5)[..., None], m


@functools.partial(jax.jit, static_argnames=("pano",))
def surrogate_images(rig: Rig, images: Array, masks: Array | None = None,
                     pano: Panorama = Panorama.hemisphere(512, 2048)) -> tuple[Array, Array]:
    """All cameras: images (N, h, w, C) -> surrogates (N, H, W, C) and masks (N, H, W).

    ``masks`` (N, h, w) overrides the rig's own masks; by default the rig's masks are used.
    """
    per_cam = () if masks is None else (masks.astype(images.dtype),)

    def one(cam, rot, trans, rig_mask, image, *mask):
        return surrogate_image(cam, image, mask[0] if mask else rig_mask, pano)

    return map_cameras(one, rig, images, *per_cam)
