"""Kalibr / TartanCalib ``camchain.yaml`` import.

Top-level keys ``cam0``, ``cam1``, ... each hold ``camera_model`` (``ds``, ``eucm``,
``pinhole`` with ``distortion_model: equidistant``, the Kannala-Brandt fisheye model, or
``omni`` with ``distortion_model: radtan`` or ``none``, the Unified model),
``intrinsics``, ``resolution`` and, from ``cam1`` on, ``T_cn_cnm1``: the 4x4 transform that maps
points of camera n-1 into camera n. The chain is composed back to camera 0 and turned into
camera-to-rig poses by :func:`gijax.io.parsing.chain_to_rig`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gijax.geometry.rig import Rig
from gijax.io.parsing import Where, chain_to_rig, check_rotation, checked_camera, floats, \
    mapping_field, resolution


def _camera(key: str, c: dict, where: Where):
    w = where.at(key)
    if not isinstance(c, dict):
        raise w.error(key, "a mapping with camera_model, intrinsics, resolution", c)
    model = mapping_field(c, "camera_model", w, "one of 'ds', 'eucm', 'pinhole', 'omni'")
    intr = mapping_field(c, "intrinsics", w, "a list of intrinsics")
    dist = c.get("distortion_model", "none")
    if model == "ds":
        v = floats(intr, 6, "intrinsics", w, "6 values [xi, alpha, fu, fv, pu, pv] for 'ds'")
        gmodel, params = "ds", dict(xi=v[0], alpha=v[1], fx=v[2], fy=v[3], cx=v[4], cy=v[5])
    elif model == "eucm":
        v = floats(intr, 6, "intrinsics", w, "6 values [alpha, beta, fu, fv, pu, pv] for 'eucm'")
        gmodel, params = "eucm", dict(alpha=v[0], beta=v[1], fx=v[2], fy=v[3], cx=v[4], cy=v[5])
    elif model == "pinhole":
        v = floats(intr, 4, "intrinsics", w, "4 values [fu, fv, pu, pv] for 'pinhole'")
        if dist != "equidistant":
            raise w.error("distortion_model", "'equidistant' for a pinhole camera (the "
                                              "Kannala-Brandt fisheye model)", dist)
        k = floats(mapping_field(c, "distortion_coeffs", w, "[k1, k2, k3, k4]"), 4,
                   "distortion_coeffs", w, "4 values [k1, k2, k3, k4]")
        gmodel = "kb"
        params = dict(fx=v[0], fy=v[1], cx=v[2], cy=v[3], k1=k[0], k2=k[1], k3=k[2], k4=k[3])
    elif model == "omni":
        v = floats(intr, 5, "intrinsics", w, "5 values [xi, fu, fv, pu, pv] for 'omni'")
        if dist == "radtan":
            k = floats(mapping_field(c, "distortion_coeffs", w, "[k1, k2, p1, p2]"), 4,
                       "distortion_coeffs", w, "4 values [k1, k2, p1, p2] for 'radtan'")
        elif dist in ("none", None):
            k = (0.0, 0.0, 0.0, 0.0)
        else:
            raise w.error("distortion_model", "'radtan' or 'none' for camera_model 'omni'", dist)
        gmodel = "omni"
        params = dict(xi=v[0], fx=v[1], fy=v[2], cx=v[3], cy=v[4], k1=k[0], k2=k[1], p1=k[2],
                      p2=k[3])
    else:
        raise w.error("camera_model", "one of 'ds', 'eucm', 'pinhole' (with distortion_model "
                                      "'equidistant'), 'omni' (with 'radtan' or 'none')", model)
    if model in ("ds", "eucm") and dist not in ("none", None):
        raise w.error("distortion_model", f"'none' for camera_model {model!r}", dist)
    res = resolution(mapping_field(c, "resolution", w, "[width, height]"), w)
    cam = checked_camera(gmodel, {k: float(x) for k, x in params.items()}, res, None, w)
    return cam, w


def is_camchain(data: dict) -> bool:
    """Whether a decoded YAML mapping looks like a camchain (some ``cam...`` key)."""
    return any(isinstance(k, str) and k.startswith("cam") for k in data)


def parse_camchain(path: Path, data: dict, frame_camera: int) -> Rig:
    """The rig of a decoded camchain; ``path`` only names the file in errors."""
    where = Where(path)
    keys = [k for k in data if isinstance(k, str) and k.startswith("cam")]
    if not keys:
        raise where.error("cam0", "at least one camera entry cam0, cam1, ...", sorted(data))
    expected = [f"cam{i}" for i in range(len(keys))]
    if sorted(keys, key=lambda k: (len(k), k)) != expected:
        raise where.error("cam0", f"consecutive camera entries {expected}", sorted(keys))
    cams, t_cn_c0 = [], []
    for i, key in enumerate(expected):
        c = data[key]
        cam, w = _camera(key, c, where)
        cams.append(cam)
        if i == 0:
            t_cn_c0.append(np.eye(4))
            continue
        t = floats(mapping_field(c, "T_cn_cnm1", w, "a 4x4 transform from cam n-1 to cam n"), 16,
                   "T_cn_cnm1", w, "a 4x4 transform").reshape(4, 4)
        if np.abs(t[3] - [0, 0, 0, 1]).max() > 1e-9:
            raise w.error("T_cn_cnm1", "a 4x4 rigid transform with last row [0, 0, 0, 1]",
                          t.tolist())
        check_rotation(t[:3, :3], "T_cn_cnm1", w)
        t_cn_c0.append(t @ t_cn_c0[-1])
    return chain_to_rig(cams, [np.linalg.inv(t) for t in t_cn_c0], frame_camera, expected,
                        where)


__all__ = ["is_camchain", "parse_camchain"]
