"""Calibration errors: the rig the network is told about differs slightly from the true one.

A real rig's calibration is off by a fraction of a degree in each camera's rotation and by a
fraction of a percent in its focal length and principal point. That changes geometry, not
pixels: the images stay rendered with the true rig, and the network is given
:func:`perturb_rig`'s rig for its sweep.

Pure and traceable: every draw comes from the key (one sub-key per camera, so adding a camera
changes no other camera's draw).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from gijax.geometry.rig import Rig
from gijax.geometry.rotations import axis_angle_to_matrix

Array = jax.Array


@dataclasses.dataclass(frozen=True)
class CalibrationError:
    """Bounds of the perturbation (each drawn uniformly within its bound, per camera).

    Attributes:
      rotation_deg: angle of the rotation error (about a uniformly random axis), degrees.
      focal: relative error of the focal length (fx and fy scaled by one factor 1 + e,
        |e| <= focal: the pixel aspect of a sensor is not in doubt).
      centre: principal point shift, as a fraction of the image width (cx) and height (cy).
    """

    rotation_deg: float = 0.5
    focal: float = 0.01
    centre: float = 0.01


def _perturb_camera(key: Array, cam, rotation: Array, error: CalibrationError):
    k_axis, k_angle, k_focal, k_centre = jax.random.split(key, 4)
    axis = jax.random.normal(k_axis, (3,), rotation.dtype)
    axis = axis / jnp.linalg.norm(axis)
    angle = jax.random.uniform(k_angle, (), rotation.dtype, 0.0, jnp.deg2rad(error.rotation_deg))
    # Right-multiplied: the error is a small turn of the camera about its own centre.
    new_rotation = rotation @ axis_angle_to_matrix(axis * angle)
    f = 1.0 + jax.random.uniform(k_focal, (), jnp.float32, -error.focal, error.focal)
    shift = jax.random.uniform(k_centre, (2,), jnp.float32, -error.centre, error.centre)
    new_cam = dataclasses.replace(cam, fx=cam.fx * f, fy=cam.fy * f,
                                  cx=cam.cx + shift[0] * cam.width,
                                  cy=cam.cy + shift[1] * cam.height)
    return new_cam, new_rotation


def perturb_rig(key: Array, rig: Rig, error: CalibrationError = CalibrationError()) -> Rig:
    """The rig with every camera's rotation and intrinsics (fx, fy, cx, cy) perturbed within
    ``error``'s bounds; translations, masks, image sizes, distortion parameters and the
    occluder are unchanged. Rotations stay orthonormal (the error is a rotation)."""
    cams, rots = [], []
    for i, cam in enumerate(rig.cameras):
        c, r = _perturb_camera(jax.random.fold_in(key, i), cam, rig.rotations[i], error)
        cams.append(c)
        rots.append(r)
    return rig.replace(cameras=tuple(cams), rotations=jnp.stack(rots))
