"""Checked reading of rig-file fields, shared by every format (gijax YAML, Kalibr, basalt).

Every malformed value raises one ``ValueError`` naming the file, the camera, the field and what
was expected (:class:`Where` builds :func:`gijax.checks.bad_document_field`'s message).
Calibration files print about 8-10 digits, so rotations are checked against
:data:`ORTHONORMAL_TOL`, and all arithmetic here is float64: the rig is rounded to float32 once,
at the end.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import numpy as np

from gijax.checks import MISSING, bad_document_field
from gijax.geometry.cameras import make_camera
from gijax.io.bounds import CAMERA_BYTES_PER_PIXEL, check_size
from gijax.geometry.rig import Rig, make_rig

# Tolerance on |R^T R - I| and on | |q| - 1 |.
ORTHONORMAL_TOL = 1e-5


class Where:
    """Builds error messages that name the file and the camera."""

    def __init__(self, path: Path, camera: Optional[str] = None):
        self.path = path
        self.camera = camera

    def at(self, camera: str) -> "Where":
        return Where(self.path, camera)

    def error(self, field: str, expected: str, found: Any) -> ValueError:
        within = None if self.camera is None else f"camera {self.camera!r}"
        return bad_document_field(self.path, field, expected, found, within=within)


def mapping_field(d: dict, key: str, where: Where, expected: str):
    """``d[key]``, or an error saying the field is missing (or ``d`` is no mapping)."""
    if not isinstance(d, dict):
        raise where.error(key, f"a mapping containing {key!r}", d)
    if key not in d:
        raise where.error(key, expected, MISSING)
    return d[key]


def floats(value, n: Optional[int], field: str, where: Where, shape_text: str) -> np.ndarray:
    """A finite float64 array with n entries (or any length when n is None), every entry within
    float32's range (the rig is rounded to float32, where a larger one would be infinite).

    With ``n`` the value is a flat list of n numbers (one number when n is 1) or, for a matrix,
    a square k x k nesting of them; the result is flat, shape (n,)."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise where.error(field, shape_text, value) from None
    if n is not None:
        k = int(round(n ** 0.5))
        if arr.shape not in {(n,), () if n == 1 else (n,), (k, k) if k * k == n > 1 else (n,)}:
            raise where.error(field, shape_text, value)
    if not np.all(np.isfinite(arr)):
        raise where.error(field, f"finite numbers ({shape_text})", value)
    if np.any(np.abs(arr) > np.finfo(np.float32).max):
        raise where.error(field, f"numbers within float32's range ({shape_text})", value)
    return arr.reshape(-1) if n is not None else arr


def check_rotation(r: np.ndarray, field: str, where: Where) -> np.ndarray:
    """``r`` itself when it is a proper rotation within :data:`ORTHONORMAL_TOL`."""
    err = np.abs(r.T @ r - np.eye(3)).max()
    if err > ORTHONORMAL_TOL or np.linalg.det(r) <= 0:
        raise where.error(field, f"a proper orthonormal 3x3 rotation (|R^T R - I| <= "
                                 f"{ORTHONORMAL_TOL}, det = +1; here |R^T R - I| = {err:.3g}, "
                                 f"det = {np.linalg.det(r):.6g})", r.tolist())
    return r


def quat_matrix(q: np.ndarray, field: str, where: Where) -> np.ndarray:
    """Hamilton (qx, qy, qz, qw) to a rotation matrix, after a unit-norm check.

    Quaternions enter gijax only from files (gijax YAML, basalt), so this is the one place they
    are turned into matrices. It is numpy float64, not JAX: calibration poses are chained and
    inverted in float64 before the rig is rounded to float32 once.
    """
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > ORTHONORMAL_TOL:
        raise where.error(field, f"a unit quaternion [qx, qy, qz, qw] (norm {norm:.6g})",
                          q.tolist())
    x, y, z, w = q / norm
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def resolution(value, where: Where) -> tuple[int, int]:
    """[width, height] as two positive integers."""
    res = floats(value, 2, "resolution", where, "[width, height], two positive integers")
    if np.any(res < 1) or np.any(res != np.round(res)):
        raise where.error("resolution", "[width, height], two positive integers", value)
    try:
        check_size("image size", int(res[0]), int(res[1]), CAMERA_BYTES_PER_PIXEL)
    except ValueError as exc:
        raise where.error("resolution", "an image size within the bounds of gijax.io.bounds",
                          f"{value} ({exc})") from None
    return int(res[0]), int(res[1])


def checked_camera(model: str, params: dict, res: tuple[int, int], fov_deg, where: Where):
    """A camera of ``model`` after checking the field of view and the focal lengths."""
    if fov_deg is not None:
        fov = floats(fov_deg, 1, "fov_deg", where, "one number of degrees in (0, 360]")
        if not 0.0 < float(fov[0]) <= 360.0:
            raise where.error("fov_deg", "one number of degrees in (0, 360]", fov_deg)
        fov_deg = float(fov[0])
    for k in ("fx", "fy"):
        if not np.float32(params[k]) > 0:       # positive once rounded to float32
            raise where.error(f"intrinsics.{k}", "a positive focal length in pixels", params[k])
    return make_camera(model, params, res[0], res[1], fov_deg)


def chain_to_rig(cams, t_c0_cn, frame_camera: int, names, where: Where) -> Rig:
    """A rig from calibrated cameras and their 4x4 camera-n-to-camera-0 transforms, with the
    rig frame equal to camera ``frame_camera`` (whose optical axis becomes the viewing axis)
    and the reference point (the panorama's centre) at the centroid of the camera centres, so
    that a ring of cameras is seen from its middle rather than from one lens."""
    if not 0 <= frame_camera < len(cams):
        raise where.error("frame_camera", f"a camera index in [0, {len(cams) - 1}]",
                          frame_camera)
    t_rig_c0 = np.linalg.inv(t_c0_cn[frame_camera])
    poses = [t_rig_c0 @ t for t in t_c0_cn]
    centres = np.stack([p[:3, 3] for p in poses])
    return make_rig(cams, np.stack([p[:3, :3] for p in poses]), centres, centres.mean(axis=0),
                    names=names)
