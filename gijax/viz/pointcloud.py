"""Point clouds from distance panoramas, written as binary little-endian PLY.

Points are ``reference + distance * ray`` in the rig frame (metres). The PLY is written to a
temporary name and renamed, so a partial file never looks complete.
"""

from __future__ import annotations

import os

import numpy as np

from gijax.evaluate.labels import usable_label
from gijax.geometry.panorama import Panorama, ray_grid
from gijax.io.paths import write_bytes_atomic


def panorama_points(distance: np.ndarray, reference, pano: Panorama | None = None,
                    valid: np.ndarray | None = None, max_distance: float = 1e3,
                    rotation=None) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) distances (m) -> points (M, 3) float32 in the rig frame and the (H, W) selection.

    Pixels with non-finite distance, distance above ``max_distance`` (sky) or ``valid`` False
    are dropped. ``pano`` defaults to the hemisphere of the distance map's size; ``rotation``
    (3, 3) is the rig's panorama-to-rig rotation (``Rig.panorama_rotation``, default identity).
    """
    distance = np.asarray(distance, np.float64)
    if distance.ndim != 2:
        raise ValueError(f"distance must be an (H, W) panorama; found shape {distance.shape}")
    pano = pano or Panorama.hemisphere(*distance.shape)
    if pano.shape != distance.shape:
        raise ValueError(f"panorama {pano.shape} does not match distance shape {distance.shape}")
    rays = np.asarray(ray_grid(pano), np.float64)
    if rotation is not None:
        rays = rays @ np.asarray(rotation, np.float64).T
    keep = usable_label(distance) & (distance <= max_distance)
    if valid is not None:
        keep &= np.asarray(valid, bool)
    pts = np.asarray(reference, np.float64) + distance[..., None] * rays
    return pts[keep].astype(np.float32), keep


def write_ply(path: str, points: np.ndarray, colours: np.ndarray | None = None) -> str:
    """Write points (M, 3) and optional uint8 RGB colours (M, 3) as binary PLY; returns path."""
    points = np.asarray(points, np.float32)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (M, 3); found {points.shape}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colours is not None:
        colours = np.asarray(colours)
        if colours.shape != points.shape:
            raise ValueError(f"colours must have shape {points.shape}; found {colours.shape}")
        if colours.dtype != np.uint8:
            raise ValueError(f"colours must be uint8 RGB; found dtype {colours.dtype}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rec = np.empty(len(points), dtype=fields)
    rec["x"], rec["y"], rec["z"] = points.T
    if colours is not None:
        rec["red"], rec["green"], rec["blue"] = colours.T
    names = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(points)}"]
    header += [f"property {names[t]} {n}" for n, t in fields]
    header.append("end_header")
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    write_bytes_atomic(path, ("\n".join(header) + "\n").encode("ascii") + rec.tobytes())
    return path
