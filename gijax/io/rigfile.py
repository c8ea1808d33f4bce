"""Rig files: the gijax YAML rig format (read and write) and calibration import.

``load_rig(name_or_path)`` accepts

* a built-in layout name (``paper-train``, ``paper-test1``, ``paper-test2``, ``paper-test3``);
* a gijax YAML rig file (top-level key ``gijax_rig: 1``, format below);
* a Kalibr / TartanCalib ``camchain.yaml`` (top-level keys ``cam0``, ``cam1``, ...; camera
  models ``ds``, ``eucm`` and ``pinhole`` with ``distortion_model: equidistant``);
* a basalt calibration JSON (``value0.T_imu_cam``, ``value0.intrinsics``, ``value0.resolution``;
  camera types ``ds``, ``eucm``, ``kb4``).

The gijax YAML format (lengths in metres, angles in degrees, pixels with integer centres)::

    gijax_rig: 1
    reference: [0.0, 0.0, 0.0]          # panorama centre in the rig frame (default: origin)
    occluder:                           # optional capped cylinder along +z (the rig body)
      {x: 0.0, y: 0.0, radius: 0.05, z_min: 0.0, z_max: 0.1}
    cameras:
      - name: cam0                      # optional, default camN
        model: ds                       # ds | eucm | kb | equidistant
        intrinsics: {fx: 232.0, fy: 232.0, cx: 611.5, cy: 513.5, xi: -0.203, alpha: 0.589}
        resolution: [1224, 1028]        # [width, height]
        fov_deg: 195.0                  # optional full field-of-view cone, default 360
        rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]   # camera-to-rig; or
        # quaternion: [qx, qy, qz, qw]                # Hamilton, camera-to-rig
        translation: [0.0, 0.0, 0.0]    # camera centre in the rig frame
        mask: cam0_mask.png             # optional, relative to this file; nonzero = valid

Intrinsics by model: ``ds`` fx fy cx cy xi alpha; ``eucm`` fx fy cx cy alpha beta; ``kb``
fx fy cx cy k1 k2 k3 k4; ``equidistant`` fx fy cx cy.

Calibration files chain their poses differently: Kalibr's ``T_cn_cnm1`` maps points of camera
n-1 into camera n; basalt's ``T_imu_cam`` maps camera points into the IMU frame. Both are turned
into camera-to-rig poses with the rig frame equal to camera ``frame_camera`` (0 unless told
otherwise), whose optical axis is then the rig's viewing axis.

Every malformed file raises one ``ValueError`` naming the file, the camera, the field and what
was expected; a missing file raises ``FileNotFoundError``.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any, Optional

import numpy as np

from gijax.geometry.cameras import CAMERA_MODELS, camera_params, make_camera
from gijax.geometry.layouts import BUILTIN_LAYOUTS, builtin_rig
from gijax.geometry.occluder import Cylinder
from gijax.geometry.rig import Rig, make_rig

FORMAT_VERSION = 1
# Tolerance on |R^T R - I| and on | |q| - 1 |: calibration files print about 8-10 digits.
ORTHONORMAL_TOL = 1e-5

_CAMERA_KEYS = {"name", "model", "intrinsics", "resolution", "fov_deg", "rotation", "quaternion",
                "translation", "mask"}
_RIG_KEYS = {"gijax_rig", "name", "reference", "occluder", "cameras"}
_OCCLUDER_KEYS = ("x", "y", "radius", "z_min", "z_max")


class _Where:
    """Builds error messages that name the file and the camera."""

    def __init__(self, path: Path, camera: Optional[str] = None):
        self.path = path
        self.camera = camera

    def at(self, camera: str) -> "_Where":
        return _Where(self.path, camera)

    def error(self, field: str, expected: str, found: Any) -> ValueError:
        where = f"{self.path}"
        if self.camera is not None:
            where += f": camera {self.camera!r}"
        return ValueError(f"{where}: field {field!r}: expected {expected}, found {found!r}")


def _require(d: dict, key: str, where: _Where, expected: str):
    if not isinstance(d, dict):
        raise where.error(key, f"a mapping containing {key!r}", d)
    if key not in d:
        raise where.error(key, expected, "nothing (the field is missing)")
    return d[key]


def _floats(value, n: Optional[int], field: str, where: _Where, shape_text: str) -> np.ndarray:
    """A finite float64 array with n entries (or any length when n is None)."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise where.error(field, shape_text, value) from None
    if n is not None and arr.size != n:
        raise where.error(field, shape_text, value)
    if not np.all(np.isfinite(arr)):
        raise where.error(field, f"finite numbers ({shape_text})", value)
    return arr.reshape(-1) if n is not None and arr.ndim == 0 else arr


def _short(value) -> float:
    """The shortest decimal that reads back as the same float32 (files stay readable)."""
    return float(str(np.float32(value)))


def _short_list(values) -> list:
    return [_short_list(v) if np.ndim(v) else _short(v) for v in np.asarray(values)]


def _fov_degrees(fov_rad) -> float:
    """Degrees with the fewest digits that convert back to the same float32 radians."""
    target = np.float32(fov_rad)
    deg = math.degrees(float(target))
    for digits in range(0, 17):
        short = round(deg, digits)
        if np.float32(np.deg2rad(np.float64(short))) == target:
            return short
    return deg


def _check_rotation(r: np.ndarray, field: str, where: _Where) -> np.ndarray:
    err = np.abs(r.T @ r - np.eye(3)).max()
    if err > ORTHONORMAL_TOL or np.linalg.det(r) <= 0:
        raise where.error(field, f"a proper orthonormal 3x3 rotation (|R^T R - I| <= "
                                 f"{ORTHONORMAL_TOL}, det = +1; here |R^T R - I| = {err:.3g}, "
                                 f"det = {np.linalg.det(r):.6g})", r.tolist())
    return r


def _quat_matrix(q: np.ndarray, field: str, where: _Where) -> np.ndarray:
    """Hamilton (qx, qy, qz, qw) to a rotation matrix in float64, after a unit-norm check."""
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


def _resolution(value, where: _Where) -> tuple[int, int]:
    res = _floats(value, 2, "resolution", where, "[width, height], two positive integers")
    if np.any(res < 1) or np.any(res != np.round(res)):
        raise where.error("resolution", "[width, height], two positive integers", value)
    return int(res[0]), int(res[1])


def _make(model: str, params: dict, res: tuple[int, int], fov_deg, where: _Where):
    if fov_deg is not None:
        fov = _floats(fov_deg, 1, "fov_deg", where, "one number of degrees in (0, 360]")
        if not 0.0 < float(fov[0]) <= 360.0:
            raise where.error("fov_deg", "one number of degrees in (0, 360]", fov_deg)
        fov_deg = float(fov[0])
    for k in ("fx", "fy"):
        if params[k] <= 0:
            raise where.error(f"intrinsics.{k}", "a positive focal length in pixels", params[k])
    return make_camera(model, params, res[0], res[1], fov_deg)


# ----------------------------------------------------------------------------- gijax YAML


def _read_yaml(path: Path) -> Any:
    import yaml

    try:
        with open(path) as f:
            return yaml.safe_load(f)
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML: {exc}") from None


def _gijax_camera(i: int, c: dict, where: _Where, root: Path):
    name = str(c.get("name", f"cam{i}")) if isinstance(c, dict) else f"cam{i}"
    w = where.at(name)
    if not isinstance(c, dict):
        raise w.error(f"cameras[{i}]", "a mapping", c)
    unknown = sorted(set(c) - _CAMERA_KEYS)
    if unknown:
        raise w.error(unknown[0], f"only the fields {sorted(_CAMERA_KEYS)}", unknown)
    model = _require(c, "model", w, f"a camera model, one of {sorted(CAMERA_MODELS)}")
    if model not in CAMERA_MODELS:
        raise w.error("model", f"one of {sorted(CAMERA_MODELS)}", model)
    names = CAMERA_MODELS[model].PARAMS
    intr = _require(c, "intrinsics", w, f"a mapping with {list(names)}")
    if not isinstance(intr, dict):
        raise w.error("intrinsics", f"a mapping with {list(names)}", intr)
    if set(intr) != set(names):
        raise w.error("intrinsics", f"exactly the {len(names)} intrinsics {list(names)} of "
                                    f"model {model!r}", sorted(intr))
    params = {k: float(_floats(intr[k], 1, f"intrinsics.{k}", w, "one number")[0]) for k in names}
    res = _resolution(_require(c, "resolution", w, "[width, height]"), w)
    cam = _make(model, params, res, c.get("fov_deg"), w)
    if ("rotation" in c) == ("quaternion" in c):
        raise w.error("rotation", "exactly one of 'rotation' (3x3) or 'quaternion' "
                                  "([qx, qy, qz, qw])", {k: c.get(k) for k in ("rotation",
                                                                               "quaternion")})
    if "rotation" in c:
        rot = _floats(c["rotation"], 9, "rotation", w, "a 3x3 matrix").reshape(3, 3)
        rot = _check_rotation(rot, "rotation", w)
    else:
        q = _floats(c["quaternion"], 4, "quaternion", w, "[qx, qy, qz, qw]")
        rot = _quat_matrix(q, "quaternion", w)
    trans = _floats(_require(c, "translation", w, "[x, y, z] in metres"), 3, "translation", w,
                    "[x, y, z] in metres")
    mask = None
    if c.get("mask") is not None:
        mask = _read_mask(root / str(c["mask"]), res, w)
    return name, cam, rot, trans, mask


def _read_mask(path: Path, res: tuple[int, int], where: _Where):
    import cv2

    if not path.is_file():
        raise FileNotFoundError(f"{where.path}: camera {where.camera!r}: field 'mask': "
                                f"mask image {path} does not exist")
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise where.error("mask", "a readable grayscale PNG", str(path))
    if img.shape != (res[1], res[0]):
        raise where.error("mask", f"an image of the camera's size {res[1]}x{res[0]} (HxW)",
                          f"{img.shape[0]}x{img.shape[1]} in {path}")
    return (img > 127).astype(np.float32)


def _read_gijax(path: Path, data: dict) -> Rig:
    where = _Where(path)
    unknown = sorted(set(data) - _RIG_KEYS)
    if unknown:
        raise where.error(unknown[0], f"only the top-level fields {sorted(_RIG_KEYS)}", unknown)
    if data.get("gijax_rig") != FORMAT_VERSION:
        raise where.error("gijax_rig", f"format version {FORMAT_VERSION}", data.get("gijax_rig"))
    cams = _require(data, "cameras", where, "a non-empty list of cameras")
    if not isinstance(cams, list) or not cams:
        raise where.error("cameras", "a non-empty list of cameras", cams)
    parsed = [_gijax_camera(i, c, where, path.parent) for i, c in enumerate(cams)]
    names = [p[0] for p in parsed]
    if len(set(names)) != len(names):
        raise where.error("cameras", "distinct camera names", names)
    reference = None
    if data.get("reference") is not None:
        reference = _floats(data["reference"], 3, "reference", where, "[x, y, z] in metres")
    occluder = None
    if data.get("occluder") is not None:
        occ = data["occluder"]
        if not isinstance(occ, dict) or set(occ) != set(_OCCLUDER_KEYS):
            raise where.error("occluder", f"a mapping with exactly {list(_OCCLUDER_KEYS)}", occ)
        vals = [np.float32(_floats(occ[k], 1, f"occluder.{k}", where, "one number")[0])
                for k in _OCCLUDER_KEYS]
        occluder = Cylinder(*vals)
    return make_rig([p[1] for p in parsed], np.stack([p[2] for p in parsed]),
                    np.stack([p[3] for p in parsed]), reference,
                    masks=[p[4] for p in parsed], occluder=occluder, names=names)


# ----------------------------------------------------------------------------- Kalibr


def _kalibr_camera(key: str, c: dict, where: _Where):
    w = where.at(key)
    if not isinstance(c, dict):
        raise w.error(key, "a mapping with camera_model, intrinsics, resolution", c)
    model = _require(c, "camera_model", w, "one of 'ds', 'eucm', 'pinhole'")
    intr = _require(c, "intrinsics", w, "a list of intrinsics")
    dist = c.get("distortion_model", "none")
    if model == "ds":
        v = _floats(intr, 6, "intrinsics", w, "6 values [xi, alpha, fu, fv, pu, pv] for 'ds'")
        gmodel, params = "ds", dict(xi=v[0], alpha=v[1], fx=v[2], fy=v[3], cx=v[4], cy=v[5])
    elif model == "eucm":
        v = _floats(intr, 6, "intrinsics", w, "6 values [alpha, beta, fu, fv, pu, pv] for 'eucm'")
        gmodel, params = "eucm", dict(alpha=v[0], beta=v[1], fx=v[2], fy=v[3], cx=v[4], cy=v[5])
    elif model == "pinhole":
        v = _floats(intr, 4, "intrinsics", w, "4 values [fu, fv, pu, pv] for 'pinhole'")
        if dist != "equidistant":
            raise w.error("distortion_model", "'equidistant' for a pinhole camera (the "
                                              "Kannala-Brandt fisheye model)", dist)
        k = _floats(_require(c, "distortion_coeffs", w, "[k1, k2, k3, k4]"), 4,
                    "distortion_coeffs", w, "4 values [k1, k2, k3, k4]")
        gmodel = "kb"
        params = dict(fx=v[0], fy=v[1], cx=v[2], cy=v[3], k1=k[0], k2=k[1], k3=k[2], k4=k[3])
    else:
        raise w.error("camera_model", "one of 'ds', 'eucm', 'pinhole' (with distortion_model "
                                      "'equidistant')", model)
    if model != "pinhole" and dist not in ("none", None):
        raise w.error("distortion_model", f"'none' for camera_model {model!r}", dist)
    res = _resolution(_require(c, "resolution", w, "[width, height]"), w)
    cam = _make(gmodel, {k: float(x) for k, x in params.items()}, res, None, w)
    return cam, w


def _read_kalibr(path: Path, data: dict, frame_camera: int) -> Rig:
    where = _Where(path)
    keys = [k for k in data if isinstance(k, str) and k.startswith("cam")]
    if not keys:
        raise where.error("cam0", "at least one camera entry cam0, cam1, ...", sorted(data))
    expected = [f"cam{i}" for i in range(len(keys))]
    if sorted(keys, key=lambda k: (len(k), k)) != expected:
        raise where.error("cam0", f"consecutive camera entries {expected}", sorted(keys))
    cams, t_cn_c0 = [], []
    for i, key in enumerate(expected):
        c = data[key]
        cam, w = _kalibr_camera(key, c, where)
        cams.append(cam)
        if i == 0:
            t_cn_c0.append(np.eye(4))
            continue
        t = _floats(_require(c, "T_cn_cnm1", w, "a 4x4 transform from cam n-1 to cam n"), 16,
                    "T_cn_cnm1", w, "a 4x4 transform").reshape(4, 4)
        if np.abs(t[3] - [0, 0, 0, 1]).max() > 1e-9:
            raise w.error("T_cn_cnm1", "a 4x4 rigid transform with last row [0, 0, 0, 1]",
                          t.tolist())
        _check_rotation(t[:3, :3], "T_cn_cnm1", w)
        t_cn_c0.append(t @ t_cn_c0[-1])
    return _chain_to_rig(cams, [np.linalg.inv(t) for t in t_cn_c0], frame_camera, expected,
                         where)


def _chain_to_rig(cams, t_c0_cn, frame_camera, names, where: _Where) -> Rig:
    """Camera-to-rig poses with the rig frame equal to camera ``frame_camera``."""
    if not 0 <= frame_camera < len(cams):
        raise where.error("frame_camera", f"a camera index in [0, {len(cams) - 1}]",
                          frame_camera)
    t_rig_c0 = np.linalg.inv(t_c0_cn[frame_camera])
    poses = [t_rig_c0 @ t for t in t_c0_cn]
    return make_rig(cams, np.stack([p[:3, :3] for p in poses]),
                    np.stack([p[:3, 3] for p in poses]), names=names)


# ----------------------------------------------------------------------------- basalt

_BASALT_MODELS = {
    "ds": ("ds", ("fx", "fy", "cx", "cy", "xi", "alpha")),
    "eucm": ("eucm", ("fx", "fy", "cx", "cy", "alpha", "beta")),
    "kb4": ("kb", ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")),
}


def _read_basalt(path: Path, data: dict, frame_camera: int) -> Rig:
    where = _Where(path)
    v = _require(data, "value0", where, "the basalt calibration object 'value0'")
    poses = _require(v, "T_imu_cam", where, "a list of camera poses {px..qw}")
    intr = _require(v, "intrinsics", where, "a list of camera intrinsics")
    res = _require(v, "resolution", where, "a list of [width, height]")
    for field, lst in (("T_imu_cam", poses), ("intrinsics", intr), ("resolution", res)):
        if not isinstance(lst, list) or not lst:
            raise where.error(f"value0.{field}", "a non-empty list, one entry per camera", lst)
    if not len(poses) == len(intr) == len(res):
        raise where.error("value0.T_imu_cam", f"as many entries as value0.intrinsics "
                                              f"({len(intr)}) and value0.resolution "
                                              f"({len(res)})", len(poses))
    cams, t_imu_cam, names = [], [], []
    for i, (pose, ci, r) in enumerate(zip(poses, intr, res)):
        w = where.at(f"cam{i}")
        names.append(f"cam{i}")
        ctype = _require(ci, "camera_type", w, f"one of {sorted(_BASALT_MODELS)}")
        if ctype not in _BASALT_MODELS:
            raise w.error("camera_type", f"one of {sorted(_BASALT_MODELS)}", ctype)
        gmodel, keys = _BASALT_MODELS[ctype]
        values = _require(ci, "intrinsics", w, f"a mapping with {list(keys)}")
        if not isinstance(values, dict) or set(values) != set(keys):
            raise w.error("intrinsics", f"exactly the {len(keys)} intrinsics {list(keys)} of "
                                        f"camera_type {ctype!r}",
                          sorted(values) if isinstance(values, dict) else values)
        params = {k: float(_floats(values[k], 1, f"intrinsics.{k}", w, "one number")[0])
                  for k in keys}
        cams.append(_make(gmodel, params, _resolution(r, w), None, w))
        fields = ("px", "py", "pz", "qx", "qy", "qz", "qw")
        if not isinstance(pose, dict) or set(pose) != set(fields):
            raise w.error("T_imu_cam", f"a mapping with exactly {list(fields)}", pose)
        vals = {k: float(_floats(pose[k], 1, f"T_imu_cam.{k}", w, "one number")[0])
                for k in fields}
        rot = _quat_matrix(np.array([vals[k] for k in ("qx", "qy", "qz", "qw")]),
                           "T_imu_cam", w)
        t = np.eye(4)
        t[:3, :3] = rot
        t[:3, 3] = [vals["px"], vals["py"], vals["pz"]]
        t_imu_cam.append(t)
    t_c0_imu = np.linalg.inv(t_imu_cam[0])
    return _chain_to_rig(cams, [t_c0_imu @ t for t in t_imu_cam], frame_camera, names, where)


# ----------------------------------------------------------------------------- public API


def load_rig(name_or_path, frame_camera: int = 0) -> Rig:
    """Load a rig from a built-in name, a gijax YAML file, a Kalibr camchain or a basalt JSON.

    Args:
      name_or_path: a built-in layout name or a file path.
      frame_camera: for calibration imports, the camera whose frame becomes the rig frame
        (its centre is the origin and the default reference point). Ignored for gijax files
        and built-ins, which carry their own frame.

    Returns:
      a :class:`~gijax.geometry.rig.Rig` (float32 leaves).

    Raises:
      FileNotFoundError: neither a built-in name nor an existing file.
      ValueError: a malformed file (the message names file, camera, field and expectation).
    """
    if isinstance(name_or_path, str) and name_or_path in BUILTIN_LAYOUTS:
        return builtin_rig(name_or_path)
    path = Path(name_or_path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such rig file, and not a built-in rig name "
                                f"(built-ins: {', '.join(sorted(BUILTIN_LAYOUTS))})")
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON: {exc}") from None
        if not isinstance(data, dict):
            raise _Where(path).error("value0", "a JSON object holding 'value0'", data)
        return _read_basalt(path, data, frame_camera)
    data = _read_yaml(path)
    if not isinstance(data, dict) or not data:
        raise _Where(path).error("cameras", "a YAML mapping: a gijax rig (gijax_rig, cameras) "
                                            "or a Kalibr camchain (cam0, cam1, ...)", data)
    if "gijax_rig" in data or "cameras" in data:
        return _read_gijax(path, data)
    if any(isinstance(k, str) and k.startswith("cam") for k in data):
        return _read_kalibr(path, data, frame_camera)
    raise _Where(path).error("cameras", "a gijax rig (gijax_rig, cameras) or a Kalibr camchain "
                                        "(cam0, cam1, ...)", sorted(map(str, data)))


def rig_to_dict(rig: Rig, mask_files: Optional[list] = None) -> dict:
    """The gijax YAML structure of a rig (plain Python values); masks by the given file names."""
    cams = []
    for i, cam in enumerate(rig.cameras):
        entry = {
            "name": rig.names[i],
            "model": cam.MODEL,
            "intrinsics": {k: _short(v) for k, v in camera_params(cam).items()},
            "resolution": [int(cam.width), int(cam.height)],
            "fov_deg": _fov_degrees(cam.fov),
            "rotation": _short_list(rig.rotations[i]),
            "translation": _short_list(rig.translations[i]),
        }
        if mask_files and mask_files[i] is not None:
            entry["mask"] = mask_files[i]
        cams.append(entry)
    out = {"gijax_rig": FORMAT_VERSION,
           "reference": _short_list(rig.reference)}
    if rig.occluder is not None:
        out["occluder"] = {k: _short(getattr(rig.occluder, k)) for k in _OCCLUDER_KEYS}
    out["cameras"] = cams
    return out


def _atomic_write(path: Path, write) -> None:
    """Write through a temporary file in the same folder, then rename over ``path``."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def save_rig(rig: Rig, path) -> Path:
    """Write ``rig`` as a gijax YAML rig file; masks go to ``<stem>_<camera>_mask.png`` beside it.

    Masks are stored as binary PNGs (value >= 0.5 is valid). ``load_rig(path)`` returns a rig
    with the same cameras, poses, reference, occluder, names and masks (float32-exact).
    """
    import cv2
    import yaml

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    mask_files = []
    for name, mask in zip(rig.names, rig.masks):
        if mask is None:
            mask_files.append(None)
            continue
        fname = f"{path.stem}_{name}_mask.png"
        img = (np.asarray(mask) >= 0.5).astype(np.uint8) * 255

        def write_png(tmp, img=img):
            if not cv2.imwrite(tmp, img):
                raise ValueError(f"{path.parent / fname}: could not write the mask PNG")

        _atomic_write(path.parent / fname, write_png)
        mask_files.append(fname)
    text = yaml.safe_dump(rig_to_dict(rig, mask_files), sort_keys=False,
                          default_flow_style=None)
    _atomic_write(path, lambda tmp: Path(tmp).write_text(
        "# gijax rig file: metres, degrees, camera-to-rig poses, integer pixel centres\n" + text))
    return path

