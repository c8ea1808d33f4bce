"""The release's resampling of the rig's raw distance image into the ground-truth panorama,
returned in gijax's panorama convention."""

from __future__ import annotations

import math

import numpy as np

from gijax.data.release.cameras import ReleaseCameraModel
from gijax.data.release.layout import LABEL_PANO
from gijax.geometry.occluder import FAR
from gijax.geometry.panorama import Panorama

BLEND_THRESHOLD_SCALE = 0.01  # BlendBy2ndOrderGradTorch threshold_scaling_factor in the release
BLEND_THRESHOLD_MAX = 10.0


def _correlate(img: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """2-D cross-correlation with replicated borders (kornia's spatial_gradient padding)."""
    r = kernel.shape[0] // 2
    pad = np.pad(img, r, mode="edge")
    h, w = img.shape
    out = np.zeros((h, w), np.float64)
    for i in range(kernel.shape[0]):
        for j in range(kernel.shape[1]):
            if kernel[i, j] != 0.0:
                out += kernel[i, j] * pad[i:i + h, j:j + w]
    return out


_GXX = np.array([[-1, 0, 2, 0, -1], [-4, 0, 8, 0, -4], [-6, 0, 12, 0, -6],
                 [-4, 0, 8, 0, -4], [-1, 0, 2, 0, -1]], np.float64)
_GXY = np.array([[-1, -2, 0, 2, 1], [-2, -4, 0, 4, 2], [0, 0, 0, 0, 0],
                 [2, 4, 0, -4, -2], [1, 2, 0, -2, -1]], np.float64)
_SOBEL2 = [k / np.abs(k).sum() for k in (_GXX, _GXY, _GXX.T)]


def blend_factor(distance: np.ndarray, scale: float = BLEND_THRESHOLD_SCALE,
                 max_threshold: float = BLEND_THRESHOLD_MAX) -> np.ndarray:
    """1 where the release takes the nearest sample instead of the bilinear one.

    The release's BlendBy2ndOrderGradTorch: the norm of the three L1-normalised 5x5 Sobel
    second derivatives (xx, xy, yy) must exceed ``clip(d * scale, scale, max_threshold)``,
    then a 3x3 erosion that ignores pixels outside the image.
    """
    d = np.asarray(distance, np.float64)
    s = np.sqrt(sum(_correlate(d, k) ** 2 for k in _SOBEL2))
    m = (s > np.clip(d * scale, scale, max_threshold)).astype(np.float64)
    pad = np.pad(m, 1, mode="constant", constant_values=np.inf)
    h, w = m.shape
    return np.min([pad[i:i + h, j:j + w] for i in range(3) for j in range(3)], axis=0)


def _bilinear(img, u, v, border: bool):
    """grid_sample bilinear, align_corners=False, on release pixel coordinates."""
    h, w = img.shape
    x, y = u - 0.5, v - 0.5
    if border:
        x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    out = np.zeros(u.shape, np.float64)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            xi, yi = x0 + dx, y0 + dy
            inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
            val = img[np.clip(yi, 0, h - 1), np.clip(xi, 0, w - 1)]
            out += np.where(inside, wx * wy * val, 0.0)
    return out


def _nearest_index(u, v, h, w, border: bool):
    """grid_sample nearest with align_corners=True (as the release's samplers use it)."""
    x = (u / w) * (w - 1)
    y = (v / h) * (h - 1)
    if border:
        x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    xi, yi = np.rint(x).astype(np.int64), np.rint(y).astype(np.int64)
    inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    return np.clip(yi, 0, h - 1), np.clip(xi, 0, w - 1), inside


class LabelResampler:
    """The release's rig-distance -> panorama resampling, returned in gijax's panorama.

    ``R_raw_label`` rotates label-frame (``rifs``) coordinates into the rig camera's frame
    (``rif``); translation is ignored, as in the release's rotation-only sampler.
    """

    def __init__(self, model: ReleaseCameraModel, R_raw_label: np.ndarray, pano: Panorama):
        self.model, self.pano = model, pano
        h, w = pano.shape
        col = (np.arange(w) + 0.5) / w
        row = (np.arange(h) + 0.5) / h
        lon, lat = np.meshgrid(-math.pi + 2 * math.pi * col,
                               pano.lat_min + (pano.lat_max - pano.lat_min) * row)
        ray_e = np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], -1)
        u, v, self.valid = model.project(ray_e @ np.asarray(R_raw_label, np.float64).T)
        self.u, self.v = u, v
        border = model.padding == "border"
        self.near = _nearest_index(u, v, model.height, model.width, border)

    def __call__(self, raw: np.ndarray) -> np.ndarray:
        m = self.model
        border = m.padding == "border"
        raw = np.asarray(raw, np.float64)
        linear = _bilinear(raw, self.u, self.v, border)
        yi, xi, inside = self.near
        nearest = np.where(inside, raw[yi, xi], 0.0)
        f = np.where(inside, blend_factor(raw)[yi, xi], 0.0)
        out = f * nearest + (1 - f) * linear
        out = np.where(self.valid, out, FAR)
        # Both panoramas grow in longitude to the right: column c is column c.
        return np.ascontiguousarray(out).astype(np.float32)


def resample_rig_distance(raw: np.ndarray, model: ReleaseCameraModel, R_raw_label: np.ndarray,
                          pano: Panorama = LABEL_PANO) -> np.ndarray:
    """One rig distance image (model's shape, metres) -> gijax panorama label (H, W) metres."""
    return LabelResampler(model, R_raw_label, pano)(raw)
