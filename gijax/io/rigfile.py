"""Rig files: the gijax YAML rig format (read and write), and :func:`load_rig`, which opens any
rig a command accepts.

``load_rig(name_or_path)`` accepts

* a built-in layout name (``paper-train``, ``paper-test1``, ``paper-test2``, ``paper-test3``);
* a gijax YAML rig file (top-level key ``gijax_rig: 1``, format below);
* a Kalibr / TartanCalib ``camchain.yaml`` (:mod:`gijax.io.kalibr`);
* a basalt calibration JSON (:mod:`gijax.io.basalt`).

The gijax YAML format (lengths in metres, angles in degrees, pixels with integer centres)::

    gijax_rig: 1
    reference: [0.0, 0.0, 0.0]          # panorama centre in the rig frame (default: origin)
    panorama_rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]  # optional panorama-to-rig rotation:
                                        # columns = longitude 0, y, pole (default: identity,
                                        # the pole on the rig's +z axis)
    occluder:                           # optional capped cylinder along +z (the rig body)
      {x: 0.0, y: 0.0, radius: 0.05, z_min: 0.0, z_max: 0.1}
    cameras:
      - name: cam0                      # optional, default camN
        model: ds                       # ds | eucm | kb | equidistant | omni
        intrinsics: {fx: 232.0, fy: 232.0, cx: 611.5, cy: 513.5, xi: -0.203, alpha: 0.589}
        resolution: [1224, 1028]        # [width, height]
        fov_deg: 195.0                  # optional full field-of-view cone, default 360
        rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]   # camera-to-rig; or
        # quaternion: [qx, qy, qz, qw]                # Hamilton, camera-to-rig
        translation: [0.0, 0.0, 0.0]    # camera centre in the rig frame
        mask: cam0_mask.png             # optional, relative to this file; nonzero = valid

Intrinsics by model: ``ds`` fx fy cx cy xi alpha; ``eucm`` fx fy cx cy alpha beta; ``kb``
fx fy cx cy k1 k2 k3 k4; ``equidistant`` fx fy cx cy; ``omni`` (Unified + radial-tangential)
fx fy cx cy xi k1 k2 p1 p2.

Calibration files are turned into camera-to-rig poses with the rig frame equal to camera
``frame_camera`` (0 unless told otherwise), whose optical axis is then the rig's viewing axis,
and the reference point (the panorama centre) at the centroid of the camera centres.

Every malformed file raises one ``ValueError`` naming the file, the camera, the field and what
was expected (:mod:`gijax.io.parsing`); a missing file raises ``FileNotFoundError``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Optional

import numpy as np

from gijax.geometry.cameras import CAMERA_MODELS, camera_params
from gijax.geometry.layouts import BUILTIN_LAYOUTS, builtin_rig
from gijax.geometry.occluder import Cylinder
from gijax.geometry.rig import Rig, make_rig
from gijax.io import basalt, kalibr
from gijax.io.masks import read_mask
from gijax.io.parsing import Where, check_rotation, checked_camera, floats, quat_matrix, \
    mapping_field, resolution
from gijax.io.paths import write_png_atomic, write_text_atomic
from gijax.io.text import one_line, read_text

FORMAT_VERSION = 1

_CAMERA_KEYS = {"name", "model", "intrinsics", "resolution", "fov_deg", "rotation", "quaternion",
                "translation", "mask"}
_RIG_KEYS = {"gijax_rig", "name", "reference", "occluder", "cameras", "panorama_rotation"}
_OCCLUDER_KEYS = ("x", "y", "radius", "z_min", "z_max")


# ----------------------------------------------------------------------------- reading


def _read_yaml(path: Path) -> Any:
    import yaml

    text = read_text(path, "rig file")
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML: {one_line(exc)}") from None


def _read_json(path: Path) -> Any:
    text = read_text(path, "calibration file")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON: {exc}") from None


def _gijax_camera(i: int, c: dict, where: Where, root: Path):
    name = str(c.get("name", f"cam{i}")) if isinstance(c, dict) else f"cam{i}"
    w = where.at(name)
    if not isinstance(c, dict):
        raise w.error(f"cameras[{i}]", "a mapping", c)
    unknown = sorted(set(c) - _CAMERA_KEYS)
    if unknown:
        raise w.error(unknown[0], f"only the fields {sorted(_CAMERA_KEYS)}", unknown)
    model = mapping_field(c, "model", w, f"a camera model, one of {sorted(CAMERA_MODELS)}")
    if not isinstance(model, str) or model not in CAMERA_MODELS:
        raise w.error("model", f"one of {sorted(CAMERA_MODELS)}", model)
    names = CAMERA_MODELS[model].PARAMS
    intr = mapping_field(c, "intrinsics", w, f"a mapping with {list(names)}")
    if not isinstance(intr, dict):
        raise w.error("intrinsics", f"a mapping with {list(names)}", intr)
    if set(intr) != set(names):
        raise w.error("intrinsics", f"exactly the {len(names)} intrinsics {list(names)} of "
                                    f"model {model!r}", sorted(intr))
    params = {k: float(floats(intr[k], 1, f"intrinsics.{k}", w, "one number")[0]) for k in names}
    res = resolution(mapping_field(c, "resolution", w, "[width, height]"), w)
    cam = checked_camera(model, params, res, c.get("fov_deg"), w)
    if ("rotation" in c) == ("quaternion" in c):
        raise w.error("rotation", "exactly one of 'rotation' (3x3) or 'quaternion' "
                                  "([qx, qy, qz, qw])", {k: c.get(k) for k in ("rotation",
                                                                               "quaternion")})
    if "rotation" in c:
        rot = floats(c["rotation"], 9, "rotation", w, "a 3x3 matrix").reshape(3, 3)
        rot = check_rotation(rot, "rotation", w)
    else:
        q = floats(c["quaternion"], 4, "quaternion", w, "[qx, qy, qz, qw]")
        rot = quat_matrix(q, "quaternion", w)
    trans = floats(mapping_field(c, "translation", w, "[x, y, z] in metres"), 3, "translation", w,
                   "[x, y, z] in metres")
    mask = None
    if c.get("mask") is not None:
        mask = read_mask(root / str(c["mask"]), (cam.height, cam.width),
                         f"{where.path}: camera {name!r}: field 'mask'")
    return name, cam, rot, trans, mask


def _parse_gijax(path: Path, data: dict) -> Rig:
    where = Where(path)
    unknown = sorted(set(data) - _RIG_KEYS)
    if unknown:
        raise where.error(unknown[0], f"only the top-level fields {sorted(_RIG_KEYS)}", unknown)
    if data.get("gijax_rig") != FORMAT_VERSION:
        raise where.error("gijax_rig", f"format version {FORMAT_VERSION}", data.get("gijax_rig"))
    cams = mapping_field(data, "cameras", where, "a non-empty list of cameras")
    if not isinstance(cams, list) or not cams:
        raise where.error("cameras", "a non-empty list of cameras", cams)
    parsed = [_gijax_camera(i, c, where, path.parent) for i, c in enumerate(cams)]
    names = [p[0] for p in parsed]
    if len(set(names)) != len(names):
        raise where.error("cameras", "distinct camera names", names)
    reference = None
    if data.get("reference") is not None:
        reference = floats(data["reference"], 3, "reference", where, "[x, y, z] in metres")
    pano_rot = None
    if data.get("panorama_rotation") is not None:
        pano_rot = np.asarray(floats(data["panorama_rotation"], 9, "panorama_rotation", where,
                                     "a 3x3 rotation matrix (panorama-to-rig)"),
                              np.float64).reshape(3, 3)
        check_rotation(pano_rot, "panorama_rotation", where)
    occluder = None
    if data.get("occluder") is not None:
        occ = data["occluder"]
        if not isinstance(occ, dict) or set(occ) != set(_OCCLUDER_KEYS):
            raise where.error("occluder", f"a mapping with exactly {list(_OCCLUDER_KEYS)}", occ)
        vals = [np.float32(floats(occ[k], 1, f"occluder.{k}", where, "one number")[0])
                for k in _OCCLUDER_KEYS]
        occluder = Cylinder(*vals)
    return make_rig([p[1] for p in parsed], np.stack([p[2] for p in parsed]),
                    np.stack([p[3] for p in parsed]), reference,
                    masks=[p[4] for p in parsed], occluder=occluder, names=names,
                    panorama_rotation=pano_rot)


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
        data = _read_json(path)
        if not isinstance(data, dict):
            raise Where(path).error("value0", "a JSON object holding 'value0'", data)
        return basalt.parse_calibration(path, data, frame_camera)
    data = _read_yaml(path)
    if not isinstance(data, dict) or not data:
        raise Where(path).error("cameras", "a YAML mapping: a gijax rig (gijax_rig, cameras) "
                                           "or a Kalibr camchain (cam0, cam1, ...)", data)
    if "gijax_rig" in data or "cameras" in data:
        return _parse_gijax(path, data)
    if kalibr.is_camchain(data):
        return kalibr.parse_camchain(path, data, frame_camera)
    raise Where(path).error("cameras", "a gijax rig (gijax_rig, cameras) or a Kalibr camchain "
                                       "(cam0, cam1, ...)", sorted(map(str, data)))


# ----------------------------------------------------------------------------- writing


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
    rot = rig.panorama_rotation
    if rot is not None and not np.allclose(np.asarray(rot), np.eye(3), atol=0.0):
        out["panorama_rotation"] = _short_list(rot)
    if rig.occluder is not None:
        out["occluder"] = {k: _short(getattr(rig.occluder, k)) for k in _OCCLUDER_KEYS}
    out["cameras"] = cams
    return out


def mask_file_name(path, camera: str) -> str:
    """The file name :func:`save_rig` gives camera ``camera``'s mask beside rig file ``path``."""
    return f"{Path(path).stem}_{camera}_mask.png"


def save_rig(rig: Rig, path) -> Path:
    """Write ``rig`` as a gijax YAML rig file; masks go to ``<stem>_<camera>_mask.png`` beside it.

    Masks are stored as binary PNGs (value >= 0.5 is valid). ``load_rig(path)`` returns a rig
    with the same cameras, poses, reference, panorama frame, occluder, names and masks
    (float32-exact).
    """
    import yaml

    path = Path(path)
    mask_files = []
    for name, mask in zip(rig.names, rig.masks):
        if mask is None:
            mask_files.append(None)
            continue
        fname = mask_file_name(path, name)
        write_png_atomic(path.parent / fname, (np.asarray(mask) >= 0.5).astype(np.uint8) * 255)
        mask_files.append(fname)
    text = yaml.safe_dump(rig_to_dict(rig, mask_files), sort_keys=False,
                          default_flow_style=None)
    write_text_atomic(path, "# gijax rig file: metres, degrees, camera-to-rig poses, integer "
                            "pixel centres\n" + text)
    return path


__all__ = ["FORMAT_VERSION", "load_rig", "mask_file_name", "rig_to_dict", "save_rig"]
