"""The rig's panorama frame: where the panorama's pole and longitude origin point in the rig, and
how much of the sphere it covers.

A rig carries the orientation of its panorama as ``Rig.panorama_rotation`` (panorama-to-rig,
stored in the rig file): column 2 is the pole (row 0 of the image, its top), column 0 the
direction of longitude 0 (the middle column), and column 1 completes a right-handed frame, so
that longitude grows to the right when the panorama is seen from its centre with the pole up
(:mod:`gijax.geometry.panorama`). The identity puts the pole on the rig's +z axis, the viewing
axis of the paper's rigs, whose cameras all look into the hemisphere around it.

Cameras looking outward around a ring (a common real rig) share no axis: a hemisphere around any
one of them shows half the scene. :func:`choose_panorama` picks the frame and coverage (the
hemisphere or the full sphere) for such rigs and says why; :func:`frame_from_up` builds the
frame for a chosen up axis.

The geometric functions here (:func:`panorama_rays`, :func:`panorama_pixels`,
:func:`frame_from_up`) are traceable; the choice is a report of concrete values (NumPy).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from gijax.geometry.panorama import Panorama, direction_to_pixel, ray_grid
from gijax.geometry.rig import Rig
from gijax.numerics import safe_norm

Array = jax.Array

COVERAGES = ("auto", "hemisphere", "sphere")
# A rig whose every optical axis lies within this angle of the panorama pole is served by the
# hemisphere around the pole (the paper's setting); otherwise auto chooses the full sphere.
HEMISPHERE_CONE_DEG = 60.0


def panorama_rotation(rig: Rig) -> Array:
    """The rig's panorama-to-rig rotation (3, 3); the identity for a rig built without one."""
    if rig.panorama_rotation is None:
        return jnp.eye(3, dtype=rig.translations.dtype)
    return rig.panorama_rotation


def panorama_rays(rig: Rig, pano: Panorama, dtype=None) -> Array:
    """(H, W, 3) unit directions of every panorama pixel centre, in the rig frame."""
    dtype = dtype or rig.translations.dtype
    return ray_grid(pano, dtype) @ panorama_rotation(rig).astype(dtype).T


def to_panorama_frame(rig: Rig, directions: Array) -> Array:
    """Rig-frame directions (..., 3) expressed in the panorama frame."""
    return directions @ panorama_rotation(rig).astype(directions.dtype)


def panorama_pixels(rig: Rig, pano: Panorama, directions: Array) -> tuple[Array, Array]:
    """Panorama pixel (col, row) of rig-frame directions (..., 3) and whether they fall inside its
    latitude range (see :func:`gijax.geometry.panorama.direction_to_pixel`)."""
    return direction_to_pixel(pano, to_panorama_frame(rig, directions))


def frame_from_up(up: Array, forward: Array) -> Array:
    """The panorama-to-rig rotation whose pole is ``up`` and whose longitude 0 is ``forward``
    projected onto the plane normal to ``up`` (both rig-frame vectors, any length; ``forward``
    must not be parallel to ``up``)."""
    z = up / safe_norm(up)
    f = forward - jnp.sum(forward * z) * z
    x = f / safe_norm(f)
    y = jnp.cross(z, x)
    return jnp.stack([x, y, z], axis=1)


def with_panorama_rotation(rig: Rig, rotation) -> Rig:
    """``rig`` with its panorama frame set to ``rotation`` (3, 3), panorama-to-rig; a concrete
    rotation must be orthonormal with determinant +1 (ValueError otherwise)."""
    rot = jnp.asarray(rotation, rig.translations.dtype)
    if rot.shape != (3, 3):
        raise ValueError(f"a panorama rotation must be 3x3; found shape {tuple(rot.shape)}")
    if not isinstance(rot, jax.core.Tracer):
        r = np.asarray(rot, np.float64)
        err = np.abs(r.T @ r - np.eye(3)).max()
        if err > 1e-4 or np.linalg.det(r) < 0:
            raise ValueError(f"the panorama rotation must be a rotation (orthonormal, det +1); "
                             f"found |R^T R - I| = {err:.3g}, det {np.linalg.det(r):+.4f}")
    return rig.replace(panorama_rotation=rot)


@dataclasses.dataclass(frozen=True)
class PanoramaChoice:
    """A chosen panorama frame: ``rotation`` (3, 3) panorama-to-rig (NumPy), ``coverage``
    ('hemisphere' or 'sphere') and ``reason``, one sentence saying why."""

    rotation: np.ndarray
    coverage: str
    reason: str

    def panorama(self, hemisphere_hw) -> Panorama:
        """The panorama of this coverage at the angular resolution of a ``hemisphere_hw``
        (H, W) hemisphere: the full sphere is (2H, W)."""
        return panorama_of(self.coverage, hemisphere_hw)


def panorama_of(coverage: str, hemisphere_hw) -> Panorama:
    """``Panorama.hemisphere(H, W)`` or ``Panorama.sphere(2H, W)`` for ``hemisphere_hw`` (H, W)."""
    h, w = (int(v) for v in hemisphere_hw)
    if coverage == "hemisphere":
        return Panorama.hemisphere(h, w)
    if coverage == "sphere":
        return Panorama.sphere(2 * h, w)
    raise ValueError(f"panorama coverage {coverage!r}; expected 'hemisphere' or 'sphere'")


def coverage_of(pano: Panorama) -> str:
    """'hemisphere' or 'sphere' for a panorama from :func:`panorama_of` (by its latitude range)."""
    return "sphere" if pano.lat_max > 1e-6 else "hemisphere"


def _axis_angles(axes: np.ndarray, pole: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(axes @ pole, -1.0, 1.0)))


def estimate_up(rig: Rig) -> tuple[np.ndarray, str]:
    """The rig's up direction from its cameras (rig frame, unit) and how it was found.

    Cameras mounted upright have their image-down axis (camera y) pointing down, so up is
    ``-mean(y_i)``. When the optical axes span a plane (a ring of outward cameras), up is that
    plane's normal, signed to agree with the cameras' up; the image axes only pick the sign.
    """
    rots = np.asarray(rig.rotations, np.float64)
    axes, downs = rots[:, :, 2], rots[:, :, 1]
    cam_up = -downs.mean(axis=0)
    if len(axes) >= 3:
        _, s, vt = np.linalg.svd(axes)
        normal = vt[-1]
        if s[-1] < 0.35 * s[0]:
            sign = 1.0 if normal @ cam_up >= 0 else -1.0
            return sign * normal, "normal of the plane of the optical axes"
    if np.linalg.norm(cam_up) > 0.1:
        return cam_up / np.linalg.norm(cam_up), "mean of the cameras' image-up axes (-y)"
    return np.array([0.0, 0.0, 1.0]), "the rig's +z axis (the cameras give no up direction)"


def choose_panorama(rig: Rig, coverage: str = "auto", up=None) -> PanoramaChoice:
    """The panorama frame and coverage for ``rig``.

    * ``up`` given (a rig-frame vector, any length): the pole is ``up``,
      longitude 0 faces camera 0's optical axis; coverage ``auto`` means the full sphere.
    * Otherwise the rig's stored frame is kept when every optical axis lies within
      :data:`HEMISPHERE_CONE_DEG` of its pole (``auto`` then means the hemisphere: the paper's
      rigs). When some camera looks further away, ``auto`` means the full sphere, and if the
      rig's frame is the default (identity) one the pole becomes the rig's estimated up axis
      (:func:`estimate_up`) with longitude 0 towards camera 0.
    """
    if coverage not in COVERAGES:
        raise ValueError(f"panorama coverage {coverage!r}; expected one of {COVERAGES}")
    rots = np.asarray(rig.rotations, np.float64)
    axes = rots[:, :, 2]
    stored = np.asarray(panorama_rotation(rig), np.float64)
    if up is not None:
        if isinstance(up, str) or np.shape(up) != (3,):
            raise ValueError(f"up must be a rig-frame vector of 3 numbers; found {up!r}")
        up_v = np.asarray(up, np.float64)
        rot = _frame_towards(up_v, axes[0])
        cov = "sphere" if coverage == "auto" else coverage
        return PanoramaChoice(rot, cov, f"pole on the given up axis {_fmt(up_v)}, longitude 0 "
                                        f"towards {rig.names[0]}")
    angles = _axis_angles(axes, stored[:, 2])
    widest = float(angles.max())
    if widest <= HEMISPHERE_CONE_DEG:
        cov = "hemisphere" if coverage == "auto" else coverage
        return PanoramaChoice(stored, cov, f"every optical axis lies within {widest:.0f} deg of "
                                           f"the panorama pole {_fmt(stored[:, 2])}")
    cov = "sphere" if coverage == "auto" else coverage
    if not np.allclose(stored, np.eye(3), atol=1e-6):
        return PanoramaChoice(stored, cov, f"the rig file's panorama frame, pole "
                                           f"{_fmt(stored[:, 2])}; cameras look up to "
                                           f"{widest:.0f} deg away from it")
    up_v, how = estimate_up(rig)
    rot = _frame_towards(up_v, axes[0])
    return PanoramaChoice(rot, cov, f"cameras look up to {widest:.0f} deg away from the rig's "
                                    f"+z axis, so the pole is the rig's up axis {_fmt(up_v)} "
                                    f"({how}), longitude 0 towards {rig.names[0]}")


def _frame_towards(up: np.ndarray, forward: np.ndarray) -> np.ndarray:
    up = up / np.linalg.norm(up)
    if abs(float(forward @ up)) > 0.999:
        # Camera 0 looks along the pole: any perpendicular direction serves as longitude 0.
        forward = np.eye(3)[int(np.argmin(np.abs(up)))]
    return np.asarray(frame_from_up(jnp.asarray(up), jnp.asarray(forward)), np.float64)


def _fmt(v) -> str:
    v = np.round(np.asarray(v, np.float64), 2) + 0.0    # no "-0.00"
    return "[" + ", ".join(f"{x:+.2f}" for x in v) + "]"


def describe_choice(choice: PanoramaChoice, pano: Panorama) -> str:
    """One line for users: coverage, size and why."""
    span = math.degrees(pano.lat_max - pano.lat_min)
    return (f"panorama: {choice.coverage} ({span:.0f} deg of latitude), {pano.height}x"
            f"{pano.width}; {choice.reason}")
