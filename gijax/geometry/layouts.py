"""Built-in rig layouts after the paper's layout figure.

All cameras are the dataset's synthetic lens: equidistant ``r = f * theta`` with a 195 degree
field of view, 1024 x 1024 pixels (f = 300 px/rad puts the 97.5 degree rim at 510.5 px from the
centre), looking along +z (up), mounted in the z = 0 plane with identity orientation. A LiDAR-like
cylinder (radius 5 cm, 10 cm tall) stands at the layout's centroid and occludes part of each view.

* ``paper-train`` / ``paper-test1``: 3 cameras on an equilateral triangle of side
  0.3095015413531889 m (the baseline behind the released GI lists); the reference point is
  camera 0's centre (the paper's "reference (first) view").
* ``paper-test2``: 3 cameras on an equilateral triangle of side 1 m; reference at the centroid.
* ``paper-test3``: 4 cameras on a 1 m square; reference at the centroid.
* ``paper-train-1m``: the training triangle widened to a 1 m side, reference still at camera 0:
  a baseline change and nothing else (``paper-test2`` also moves the reference point), the
  premise of the paper's first figure.

Use :func:`gijax.geometry.rig.scale_rig` for smaller images (the CPU presets use 1/4).
"""

from __future__ import annotations

import math

import numpy as np

from gijax.geometry.cameras import make_camera
from gijax.geometry.occluder import Cylinder
from gijax.geometry.rig import Rig, make_rig, with_occlusion_masks

TRAIN_BASELINE = 0.3095015413531889
"""Side (m) of the training triangle: the baseline behind the released G16 and G8 lists."""
IMAGE_SIZE = 1024
FOCAL = 300.0
FOV_DEG = 195.0
LIDAR_RADIUS = 0.05
LIDAR_HEIGHT = 0.10


def synthetic_camera(size: int = IMAGE_SIZE, focal: float = FOCAL, fov_deg: float = FOV_DEG):
    c = (size - 1) / 2.0
    return make_camera("equidistant", dict(fx=focal, fy=focal, cx=c, cy=c), size, size, fov_deg)


def _triangle(side: float) -> np.ndarray:
    circum = side / math.sqrt(3.0)
    angles = np.deg2rad([90.0, 210.0, 330.0])
    return np.stack([circum * np.cos(angles), circum * np.sin(angles), np.zeros(3)], -1)


def _square(side: float) -> np.ndarray:
    h = side / 2.0
    return np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])


def layout_rig(positions: np.ndarray, reference: np.ndarray, masks: bool = True) -> Rig:
    n = len(positions)
    centroid = positions.mean(0)
    occ = Cylinder(*(np.float32(v) for v in (centroid[0], centroid[1], LIDAR_RADIUS, 0.0,
                                             LIDAR_HEIGHT)))
    rig = make_rig([synthetic_camera() for _ in range(n)], np.tile(np.eye(3), (n, 1, 1)),
                   positions, reference, occluder=occ)
    return with_occlusion_masks(rig) if masks else rig


def _paper_train() -> Rig:
    p = _triangle(TRAIN_BASELINE)
    return layout_rig(p, p[0])


def _paper_train_1m() -> Rig:
    p = _triangle(1.0)
    return layout_rig(p, p[0])


def _paper_test2() -> Rig:
    p = _triangle(1.0)
    return layout_rig(p, p.mean(0))


def _paper_test3() -> Rig:
    p = _square(1.0)
    return layout_rig(p, p.mean(0))


BUILTIN_LAYOUTS = {
    "paper-train": _paper_train,
    "paper-test1": _paper_train,
    "paper-test2": _paper_test2,
    "paper-test3": _paper_test3,
    "paper-train-1m": _paper_train_1m,
}


def builtin_rig(name: str) -> Rig:
    """A built-in layout by name (see the module docstring)."""
    if name not in BUILTIN_LAYOUTS:
        raise ValueError(f"unknown built-in rig {name!r}; expected one of {sorted(BUILTIN_LAYOUTS)}")
    return BUILTIN_LAYOUTS[name]()
