"""basalt calibration JSON import.

``value0`` holds three lists with one entry per camera: ``T_imu_cam`` (``px py pz qx qy qz qw``,
the pose that maps camera points into the IMU frame, Hamilton quaternion), ``intrinsics``
(``camera_type`` ``ds``, ``eucm`` or ``kb4`` and a mapping of its intrinsics) and
``resolution`` ([width, height]). The poses are re-expressed relative to camera 0 and turned
into camera-to-rig poses by :func:`gijax.io.parsing.chain_to_rig`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gijax.geometry.rig import Rig
from gijax.io.parsing import Where, chain_to_rig, checked_camera, floats, mapping_field, \
    quat_matrix, resolution

# basalt camera_type -> (gijax model, intrinsics names shared by both)
MODELS = {
    "ds": ("ds", ("fx", "fy", "cx", "cy", "xi", "alpha")),
    "eucm": ("eucm", ("fx", "fy", "cx", "cy", "alpha", "beta")),
    "kb4": ("kb", ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")),
}
_POSE_FIELDS = ("px", "py", "pz", "qx", "qy", "qz", "qw")


def _camera(ci, r, w: Where):
    ctype = mapping_field(ci, "camera_type", w, f"one of {sorted(MODELS)}")
    if not isinstance(ctype, str) or ctype not in MODELS:
        raise w.error("camera_type", f"one of {sorted(MODELS)}", ctype)
    gmodel, keys = MODELS[ctype]
    values = mapping_field(ci, "intrinsics", w, f"a mapping with {list(keys)}")
    if not isinstance(values, dict) or set(values) != set(keys):
        raise w.error("intrinsics", f"exactly the {len(keys)} intrinsics {list(keys)} of "
                                    f"camera_type {ctype!r}",
                      sorted(values) if isinstance(values, dict) else values)
    params = {k: float(floats(values[k], 1, f"intrinsics.{k}", w, "one number")[0])
              for k in keys}
    return checked_camera(gmodel, params, resolution(r, w), None, w)


def _pose(pose, w: Where) -> np.ndarray:
    """The 4x4 camera-to-IMU transform of one ``T_imu_cam`` entry."""
    if not isinstance(pose, dict) or set(pose) != set(_POSE_FIELDS):
        raise w.error("T_imu_cam", f"a mapping with exactly {list(_POSE_FIELDS)}", pose)
    vals = {k: float(floats(pose[k], 1, f"T_imu_cam.{k}", w, "one number")[0])
            for k in _POSE_FIELDS}
    t = np.eye(4)
    t[:3, :3] = quat_matrix(np.array([vals[k] for k in ("qx", "qy", "qz", "qw")]),
                            "T_imu_cam", w)
    t[:3, 3] = [vals["px"], vals["py"], vals["pz"]]
    return t


def parse_calibration(path: Path, data: dict, frame_camera: int) -> Rig:
    """The rig of a decoded basalt calibration; ``path`` only names the file in errors."""
    where = Where(path)
    v = mapping_field(data, "value0", where, "the basalt calibration object 'value0'")
    poses = mapping_field(v, "T_imu_cam", where, "a list of camera poses {px..qw}")
    intr = mapping_field(v, "intrinsics", where, "a list of camera intrinsics")
    res = mapping_field(v, "resolution", where, "a list of [width, height]")
    for field, lst in (("T_imu_cam", poses), ("intrinsics", intr), ("resolution", res)):
        if not isinstance(lst, list) or not lst:
            raise where.error(f"value0.{field}", "a non-empty list, one entry per camera", lst)
    if not len(poses) == len(intr) == len(res):
        raise where.error("value0.T_imu_cam", f"as many entries as value0.intrinsics "
                                              f"({len(intr)}) and value0.resolution "
                                              f"({len(res)})", len(poses))
    names = [f"cam{i}" for i in range(len(poses))]
    cams, t_imu_cam = [], []
    for name, pose, ci, r in zip(names, poses, intr, res):
        w = where.at(name)
        cams.append(_camera(ci, r, w))
        t_imu_cam.append(_pose(pose, w))
    t_c0_imu = np.linalg.inv(t_imu_cam[0])
    return chain_to_rig(cams, [t_c0_imu @ t for t in t_imu_cam], frame_camera, names, where)


__all__ = ["MODELS", "parse_calibration"]
