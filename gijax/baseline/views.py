"""Matching views: the image each camera is resampled to before sphere-sweep matching.

A view is described by a hashable :class:`MatchView` (static under ``jit``):

* ``fisheye``: the camera's own lens on an image resized to ``size`` pixels wide (the height
  keeps the lens image's aspect ratio). Resampling is then a plain resize that keeps the
  lens geometry, which is what the original real-time sphere-sweep stereo matches on.
* ``equirect``: the hemisphere in front of the lens (latitude -90..0 deg around the optical
  axis), ``size / 2`` rows by ``2 * size`` columns, i.e. ``size**2`` pixels like the fisheye
  view.

All directions below are in the camera frame (x right, y down, z forward); pixel centres are
integers.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from gijax.checks import bad_field
from gijax.geometry import cameras as cam_lib
from gijax.geometry.panorama import Panorama, direction_to_pixel, ray_grid
from gijax.sampling import bilinear_sample

Array = jax.Array
VIEW_KINDS = ("fisheye", "equirect")


@dataclasses.dataclass(frozen=True)
class MatchView:
    """Kind (``fisheye`` or ``equirect``) and width in pixels of the matching image."""

    kind: str = "fisheye"
    size: int = 512

    def __post_init__(self):
        if self.kind not in VIEW_KINDS:
            raise bad_field("MatchView", "kind", f"one of {VIEW_KINDS}", self.kind)
        if int(self.size) < 8:
            raise bad_field("MatchView", "size", "at least 8 pixels", self.size)


def _panorama(view: MatchView) -> Panorama:
    return Panorama.hemisphere(max(view.size // 2, 1), 2 * view.size)


def view_camera(view: MatchView, cam):
    """The fisheye view's virtual camera: ``cam`` on an image ``view.size`` pixels wide."""
    return cam_lib.scale_camera(cam, view.size / cam.width)


def view_rays(view: MatchView, cam) -> tuple[Array, Array]:
    """Unit rays (H, W, 3) of every matching-image pixel and whether the lens sees them (H, W)."""
    if view.kind == "fisheye":
        v = view_camera(view, cam)
        rays, ok = cam_lib.unproject(v, cam_lib.pixel_grid(v.width, v.height))
        return rays, ok
    rays = ray_grid(_panorama(view), jnp.result_type(cam.fx))
    _, ok = cam_lib.project(cam, rays)
    return rays, ok


def view_pixels(view: MatchView, cam, points: Array) -> tuple[Array, Array]:
    """Camera-frame points (..., 3) to matching-image pixels (..., 2) and validity (...).

    Valid means the lens sees the point and it lands inside the matching image.
    """
    if view.kind == "fisheye":
        return cam_lib.project(view_camera(view, cam), points)
    pano = _panorama(view)
    px, ok = direction_to_pixel(pano, points)
    _, lens_ok = cam_lib.project(cam, points)
    inside = (px[..., 1] >= -0.5) & (px[..., 1] <= pano.height - 0.5)
    return px, ok & lens_ok & inside


def view_image(view: MatchView, cam, image: Array, mask: Array) -> tuple[Array, Array]:
    """Resample a raw image (h, w, C) in [0, 1] and its mask (h, w) to the matching view.

    Returns the view image (H, W, C), 0 where invalid, and a binary float mask (H, W): 1 where
    the lens sees the pixel and the bilinearly resampled mask is above 0.5.
    """
    rays, ok = view_rays(view, cam)
    src, src_ok = cam_lib.project(cam, rays)
    ok = ok & src_ok
    img, img_ok = bilinear_sample(image, src, ok)
    m, _ = bilinear_sample(mask[..., None].astype(image.dtype), src, ok)
    valid = img_ok & (m[..., 0] > 0.5)
    return img * valid[..., None], valid.astype(image.dtype)


def sample_mask_nearest(mask: Array, px: Array, valid: Array) -> Array:
    """Nearest-pixel lookup of a (H, W) mask at pixels (..., 2); False where ``valid`` is False."""
    h, w = mask.shape
    col = jnp.clip(jnp.round(px[..., 0]), 0, w - 1).astype(jnp.int32)
    row = jnp.clip(jnp.round(px[..., 1]), 0, h - 1).astype(jnp.int32)
    return valid & (mask[row, col] > 0.5)
