"""Surrogate images: each raw fisheye resampled to the hemisphere in front of its lens.

The network consumes, per camera, an equirectangular image of the hemisphere around that
camera's optical axis (latitude -90..0 deg with the pole on the axis, longitude -180..180 deg;
512 x 2048 in the paper). Pixels the lens does not see are 0; the per-camera mask is resampled beside the colours.
Sampling is bilinear by a 4-neighbour gather (:func:`gijax.sampling.bilinear_sample`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from gijax.geometry import cameras as cam_lib
from gijax.geometry.panorama import Panorama, ray_grid
from gijax.geometry.rig import Rig, map_cameras
from gijax.sampling import bilinear_sample

Array = jax.Array


def surrogate_grid(cam, pano: Panorama) -> tuple[Array, Array]:
    """(H, W, 2) fisheye pixel coordinates of every surrogate pixel, and their validity (in the
    camera's precision: a float64 camera gets float64 rays)."""
    rays = ray_grid(pano, jnp.result_type(cam.fx, jnp.float32))
    return cam_lib.project(cam, rays)


def surrogate_maps(rig: Rig, pano: Panorama) -> tuple[Array, Array]:
    """All cameras' surrogate grids: (N, H, W, 2) fisheye pixels and (N, H, W) validity.

    They depend only on the rig's intrinsics, so a loader or an exported graph computes them
    once and reuses them for every sample.
    """
    return map_cameras(lambda cam, *_: surrogate_grid(cam, pano), rig)


def resample_surrogate(px: Array, ok: Array, image: Array,
                       mask: Array | None = None) -> tuple[Array, Array]:
    """One camera's surrogate from its grid: image (h, w, C), mask (h, w) -> (H, W, C), (H, W).

    Colours are sampled bilinearly and are 0 where the lens does not see (outside its field of
    view or image); they are not zeroed under the rig mask, as in the release, whose network
    sees the rig body and learns to ignore it through the mask. The mask is resampled
    bilinearly too (fractional at mask edges) and is 0 outside the lens; without a mask the
    lens validity (0 / 1) is returned in its place.
    """
    img, ok_img = bilinear_sample(image, px, ok)
    if mask is None:
        return img, ok_img.astype(img.dtype)
    m, _ = bilinear_sample(mask[..., None].astype(image.dtype), px, ok)
    return img, m[..., 0] * ok_img


def resample_surrogates(px: Array, ok: Array, images: Array,
                        masks: Array | None = None) -> tuple[Array, Array]:
    """:func:`resample_surrogate` for every camera: grids (N, H, W, 2), (N, H, W) from
    :func:`surrogate_maps`, images (N, h, w, C), masks (N, h, w) or None."""
    return jax.vmap(resample_surrogate)(px, ok, images, masks)


def surrogate_image(cam, image: Array, mask: Array, pano: Panorama) -> tuple[Array, Array]:
    """One camera: image (h, w, C) float and mask (h, w) -> surrogate (H, W, C) and mask (H, W)
    (see :func:`resample_surrogate`)."""
    return resample_surrogate(*surrogate_grid(cam, pano), image, mask)


def check_images(rig: Rig, images, masks=None) -> None:
    """ValueError unless ``images`` (N, h, w, C) and ``masks`` (N, h, w) fit the rig's cameras."""
    n = rig.num_cameras
    shape = tuple(np.shape(images))
    if len(shape) != 4:
        raise ValueError(f"images must have shape (num_cameras, height, width, channels); "
                         f"found shape {shape}")
    if shape[0] != n:
        raise ValueError(f"the rig has {n} cameras but {shape[0]} images were given")
    for i, cam in enumerate(rig.cameras):
        if shape[1:3] != (cam.height, cam.width):
            raise ValueError(f"image {i} ({rig.names[i] if rig.names else i}) must be "
                             f"{cam.height} x {cam.width} (height x width) for the rig; found "
                             f"{shape[1]} x {shape[2]}")
    if shape[3] not in (1, 3):
        raise ValueError(f"images must have 1 or 3 channels; found {shape[3]}")
    if masks is not None:
        mshape = tuple(np.shape(masks))
        if mshape != shape[:3]:
            raise ValueError(f"masks must have shape {shape[:3]} (num_cameras, height, width) "
                             f"to match the images; found {mshape}")


def as_float_image(images) -> Array:
    """Integer images (uint8, 0..255) become float32 in [0, 1]; float images are kept."""
    images = jnp.asarray(images)
    if jnp.issubdtype(images.dtype, jnp.integer):
        return images.astype(jnp.float32) / 255.0
    if not jnp.issubdtype(images.dtype, jnp.floating):
        raise ValueError(f"images must be uint8 or float; found dtype {images.dtype}")
    return images


@functools.partial(jax.jit, static_argnames=("pano",))
def surrogate_images(rig: Rig, images: Array, masks: Array | None = None,
                     pano: Panorama = Panorama.hemisphere(512, 2048)) -> tuple[Array, Array]:
    """All cameras: images (N, h, w, C) -> surrogates (N, H, W, C) and masks (N, H, W).

    ``images`` are float (colours in [0, 1]) or uint8 (scaled to [0, 1]). ``masks`` (N, h, w),
    1 = valid, overrides the rig's own masks; by default the rig's masks are used. Shapes are
    checked against the rig's cameras when the function is traced (ValueError).
    """
    check_images(rig, images, masks)
    images = as_float_image(images)
    per_cam = () if masks is None else (jnp.asarray(masks).astype(images.dtype),)

    def one(cam, rot, trans, rig_mask, image, *mask):
        return surrogate_image(cam, image, mask[0] if mask else rig_mask, pano)

    return map_cameras(one, rig, images, *per_cam)
