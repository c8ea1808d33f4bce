"""Pure-function geometry: camera models, rotations, panoramas, rigs and built-in layouts."""

from gijax.geometry.cameras import (CAMERA_MODELS, EUCM, Camera, DoubleSphere, Equidistant,
                                    KannalaBrandt, Unified, make_camera, pixel_grid, project,
                                    scale_camera, unproject)
from gijax.geometry.layouts import BUILTIN_LAYOUTS, builtin_rig
from gijax.geometry.panorama import Panorama, ray_grid
from gijax.geometry.rig import Rig, make_rig, map_cameras, project_rig_points, scale_rig

__all__ = [
    "CAMERA_MODELS", "EUCM", "Camera", "DoubleSphere", "Equidistant", "KannalaBrandt",
    "Unified", "make_camera", "pixel_grid", "project", "scale_camera", "unproject", "BUILTIN_LAYOUTS",
    "builtin_rig", "Panorama", "ray_grid", "Rig", "make_rig", "map_cameras",
    "project_rig_points", "scale_rig",
]
