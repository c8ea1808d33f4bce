"""The manifest's ``camera_models`` entries: the release's projection (for the label
resampling) and their conversion to gijax camera models (for the input cameras).

The release measures pixel coordinates from the image corner (pixel centres at i + 0.5);
gijax from the first pixel's centre, so principal points lose 0.5 px on conversion.
"""

from __future__ import annotations

import math

import numpy as np

from gijax.data import format as fmt
from gijax.geometry import cameras as cam_lib
from gijax.io.parsing import Where, checked_camera, floats, resolution

SUPPORTED_MODELS = ("DoubleSphere", "LinearSphere")


def _shape(spec, where) -> tuple[int, int]:
    """shape_struct (H, W): positive and within the image-size bounds."""
    ss = fmt.document_field(spec, "shape_struct", where, dict)
    h = fmt.document_field(ss, "H", f"{where} shape_struct", int)
    w = fmt.document_field(ss, "W", f"{where} shape_struct", int)
    resolution([w, h], Where(f"{where} shape_struct"))
    return int(h), int(w)


def _num(spec, key, where) -> float:
    """A finite number (JSON's NaN and Infinity are refused)."""
    value = fmt.document_field(spec, key, where, (int, float))
    return float(floats(value, 1, key, Where(where), "one finite number")[0])


def _fov(spec, where) -> float:
    fov = _num(spec, "fov_degree", where)
    if not 0.0 < fov <= 360.0:
        raise ValueError(f"{where}: field 'fov_degree' must lie in (0, 360] degrees; found {fov}")
    return fov


class ReleaseCameraModel:
    """One entry of the manifest's ``camera_models``, projecting as the release's
    ``mvs_utils.camera_models`` does (release pixel coordinates: centres at i + 0.5).

    Only what the label resampling needs: :meth:`project`. Types: DoubleSphere, LinearSphere,
    Equirectangular. ``padding`` is how the release's grid_sample treats samples outside the
    image: zeros for fisheye models, the border for Equirectangular.
    """

    def __init__(self, spec: dict, where: str):
        self.where = where
        self.type = fmt.document_field(spec, "type", where, str)
        self.height, self.width = _shape(spec, where)
        self.padding = "zeros"
        if self.type == "DoubleSphere":
            for k in ("fx", "fy", "cx", "cy", "xi", "alpha"):
                setattr(self, k, _num(spec, k, where))
            self.fov_degree = _fov(spec, where)
            a, xi = self.alpha, self.xi
            if not 0.0 <= a <= 1.0 or self.fx <= 0 or self.fy <= 0:
                raise ValueError(f"{where}: DoubleSphere needs alpha in [0, 1] and positive fx, "
                                 f"fy; found alpha={a}, fx={self.fx}, fy={self.fy}")
            w1 = a / (1 - a) if a <= 0.5 else (1 - a) / a
            radicand = 2 * w1 * xi + xi * xi + 1
            if not radicand > 0:
                raise ValueError(f"{where}: DoubleSphere xi={xi} with alpha={a} has no valid "
                                 f"projection region")
            self.w2 = (w1 + xi) / math.sqrt(radicand)
        elif self.type == "LinearSphere":
            self.fov_degree = _fov(spec, where)
            if self.height != self.width:
                raise ValueError(f"{where}: a LinearSphere image must be square; found "
                                 f"shape_struct H={self.height}, W={self.width}")
        elif self.type == "Equirectangular":
            self.padding = "border"
            at = Where(where)
            lon = floats(spec.get("longitude_span", [-math.pi, math.pi]), 2, "longitude_span",
                         at, "2 numbers (radians)")
            lat = floats(spec.get("latitude_span", [-math.pi / 2, math.pi / 2]), 2,
                         "latitude_span", at, "2 numbers (radians)")
            if not (lon[1] > lon[0] and lat[1] > lat[0]):
                raise ValueError(f"{where}: longitude_span and latitude_span must be increasing; "
                                 f"found {lon.tolist()}, {lat.tolist()}")
            self.lon0, self.lat0, self.lat1 = float(lon[0]), float(lat[0]), float(lat[1])
            self.lon_span = float(lon[1]) - float(lon[0])
            if spec.get("open_span", False):
                self.lon_span *= (self.width - 1) / self.width
        else:
            raise ValueError(f"{where}: camera model type {self.type!r} is not supported for the "
                             f"rig's distance labels; supported: DoubleSphere, LinearSphere, "
                             f"Equirectangular")

    def project(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points (..., 3) -> release pixel coordinates u, v and validity, as the release."""
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.type == "DoubleSphere":
                d1 = np.sqrt(x * x + y * y + z * z)
                d2 = np.sqrt(x * x + y * y + (self.xi * d1 + z) ** 2)
                t = self.alpha * d2 + (1 - self.alpha) * (self.xi * d1 + z)
                u, v = self.fx * x / t + self.cx, self.fy * y / t + self.cy
                angle = np.arctan2(np.sqrt(x * x + y * y), z)
                valid = (z > -self.w2 * d1) & (angle <= math.radians(self.fov_degree) / 2)
            elif self.type == "LinearSphere":
                ph = np.arccos(z / np.sqrt(x * x + y * y + z * z))
                th = np.arctan2(y, x)
                r = ph * self.width / math.radians(self.fov_degree)
                u, v = r * np.cos(th) + self.width / 2, r * np.sin(th) + self.height / 2
                # The release's LinearSphere checks only that the pixel is inside the image.
                valid = (u >= 0) & (u < self.width) & (v >= 0) & (v < self.height)
            else:
                lat = np.arctan2(y, np.hypot(z, x))
                lon = np.arctan2(x, z)
                u = (lon - self.lon0) / self.lon_span * self.width
                v = (lat - self.lat0) / (self.lat1 - self.lat0) * self.height
                valid = np.ones(u.shape, bool)
        valid &= np.isfinite(u) & np.isfinite(v)
        return np.where(valid, u, 0.0), np.where(valid, v, 0.0), valid


def gijax_camera(spec: dict, where: str):
    """The gijax camera model of a manifest ``camera_models`` entry (input cameras).

    DoubleSphere -> ``ds`` with the same fx, fy, xi, alpha and fov, cx and cy minus 0.5 (pixel
    centre convention); LinearSphere (r = theta * W / fov) -> ``equidistant`` with
    fx = fy = W / fov_rad and the principal point at the image centre. Other release types
    (Equirectangular, Pinhole, Ocam) have no gijax camera model and are refused.
    """
    kind = fmt.document_field(spec, "type", where, str)
    h, w = _shape(spec, where)
    if kind == "DoubleSphere":
        p = {k: _num(spec, k, where) for k in ("fx", "fy", "cx", "cy", "xi", "alpha")}
        p["cx"] -= 0.5
        p["cy"] -= 0.5
        return checked_camera("ds", p, (w, h), _fov(spec, where), Where(where))
    if kind == "LinearSphere":
        if h != w:
            raise ValueError(f"{where}: a LinearSphere image must be square; found "
                             f"shape_struct H={h}, W={w}")
        fov_deg = _fov(spec, where)
        f = w / math.radians(fov_deg)
        c = w / 2 - 0.5
        return checked_camera("equidistant", {"fx": f, "fy": f, "cx": c, "cy": c}, (w, h),
                              fov_deg, Where(where))
    raise ValueError(f"{where}: camera model type {kind!r} has no gijax equivalent for an input "
                     f"camera; supported: {', '.join(SUPPORTED_MODELS)} (gijax models: "
                     f"{', '.join(sorted(cam_lib.CAMERA_MODELS))})")
