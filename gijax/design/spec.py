"""What a rig design optimises over: the design space and the settings of its objective.

A layout is ``num_cameras`` identical fisheye cameras (the dataset's synthetic lens by default)
whose centres lie in the rig's mounting plane (optionally at a height above it) inside a
footprint, each with an orientation given as an axis-angle vector. The platform carries a fixed
LiDAR-like cylinder at the footprint's centre (the occluder of the paper's rigs). The rig's
reference point (the panorama centre) is the centroid of the camera centres, as in the paper's
wide test layouts.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp

from gijax.checks import bad_field
from gijax.geometry.layouts import FOCAL, FOV_DEG, IMAGE_SIZE, LIDAR_HEIGHT, LIDAR_RADIUS
from gijax.geometry.panorama import Panorama

Array = jax.Array
SHAPES = ("square", "disc")


@dataclasses.dataclass(frozen=True)
class DesignSpec:
    """Design space, constraints and objective settings; hashable (static under ``jit``).

    Design space and constraints (metres, degrees):
      num_cameras: the fixed number of cameras (the parameter arrays have this many rows).
      footprint: side of the square, or diameter of the disc, centred on the rig origin, that
        must contain every camera centre.
      shape: 'square' or 'disc'.
      min_separation: smallest allowed distance between two camera centres.
      occluder_radius, occluder_height: the cylinder at the footprint's centre (z from 0 to
        ``occluder_height``).
      occluder_clearance: a camera centre must stay this far outside the cylinder's radius
        (the lens housing needs room), measured in the mounting plane.
      orientations: optimise the orientations (else every camera looks along +z).
      max_tilt_deg: largest angle between a camera's optical axis and +z.
      heights: optimise the cameras' heights above the mounting plane (else all at z = 0).
      height_range: (low, high) allowed heights.
      slack: the optimiser enforces the separation, clearance, tilt and height constraints this
        much tighter (metres for distances and heights; ``100 * slack`` degrees for the tilt)
        than stated, so that a penalty that is nearly but not exactly zero at the optimum still
        leaves the layout feasible.

    Objective (see :mod:`gijax.design.objective`):
      num_candidates, d_min, d_max: the rig-aware GI list whose steps are measured.
      pano: panorama rays the objective averages over (a small hemisphere grid).
      samples: distances (geometric over [d_min, d_max]) at which visibility is tested.
      fov_softness_deg: width of the sigmoid on the angular margin to the field-of-view edge.
      occluder_softness: width (metres) of the sigmoid on the ray's distance to the occluder.
      pixel_error: the matching error (pixels) the resolution is quoted for.
      coverage_weight: extra reward per unit of (soft) coverage fraction, 1/m.
      penalty_weight: weight of the squared constraint violations (1/m per m^2).
      camera_size, focal, fov_deg: the equidistant camera (pixels, pixels per radian, degrees).
    """

    num_cameras: int = 4
    footprint: float = 1.0
    shape: str = "square"
    min_separation: float = 0.2
    occluder_radius: float = LIDAR_RADIUS
    occluder_height: float = LIDAR_HEIGHT
    occluder_clearance: float = 0.05
    orientations: bool = True
    max_tilt_deg: float = 30.0
    heights: bool = False
    height_range: tuple = (0.0, 0.2)
    slack: float = 0.005
    num_candidates: int = 16
    d_min: float = 0.5
    d_max: float = 100.0
    pano: Panorama = Panorama.hemisphere(8, 32)
    samples: int = 4
    fov_softness_deg: float = 2.0
    occluder_softness: float = 0.01
    pixel_error: float = 1.0
    coverage_weight: float = 0.0
    penalty_weight: float = 1000.0
    camera_size: int = IMAGE_SIZE
    focal: float = FOCAL
    fov_deg: float = FOV_DEG

    def __post_init__(self):
        def bad(field, expected, found):
            raise bad_field("DesignSpec", field, expected, found)

        if isinstance(self.num_cameras, bool) or not isinstance(self.num_cameras, int) \
                or self.num_cameras < 2:
            bad("num_cameras", "an integer >= 2", self.num_cameras)
        if self.shape not in SHAPES:
            bad("shape", f"one of {SHAPES}", self.shape)
        for f in ("footprint", "occluder_radius", "occluder_height", "focal", "fov_deg",
                  "pixel_error", "fov_softness_deg", "occluder_softness"):
            v = getattr(self, f)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                bad(f, "a finite number > 0", v)
        for f in ("min_separation", "occluder_clearance", "slack", "coverage_weight",
                  "penalty_weight"):
            v = getattr(self, f)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                bad(f, "a finite number >= 0", v)
        if not 0 <= self.max_tilt_deg < 90:
            bad("max_tilt_deg", "in [0, 90) degrees", self.max_tilt_deg)
        if len(self.height_range) != 2 or not self.height_range[0] <= self.height_range[1]:
            bad("height_range", "a pair (low, high) with low <= high", self.height_range)
        if not 0 < self.d_min < self.d_max:
            bad("d_min/d_max", "0 < d_min < d_max", (self.d_min, self.d_max))
        if self.num_candidates < 3:
            bad("num_candidates", "an integer >= 3", self.num_candidates)
        if self.samples < 2:
            bad("samples", "an integer >= 2", self.samples)
        if not isinstance(self.pano, Panorama):
            bad("pano", "a gijax Panorama", self.pano)

    def replace(self, **kw) -> "DesignSpec":
        return dataclasses.replace(self, **kw)

    @property
    def half_size(self) -> float:
        """Half the footprint's side (square) or its radius (disc), metres."""
        return 0.5 * self.footprint


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Layout:
    """The free parameters of a layout (a pytree; a leading batch axis is allowed).

    positions: (N, 2) camera centres in the mounting plane, metres.
    heights: (N,) heights above the plane, metres (held at 0 unless ``spec.heights``).
    rotvecs: (N, 3) axis-angle orientations (camera-to-rig), radians (held at 0 unless
      ``spec.orientations``).
    """

    positions: Array
    heights: Array
    rotvecs: Array

    def replace(self, **kw) -> "Layout":
        return dataclasses.replace(self, **kw)


def make_layout(positions, heights=None, rotvecs=None, dtype=None) -> Layout:
    """A :class:`Layout` from (N, 2) positions; heights and orientations default to zero."""
    positions = jnp.asarray(positions, dtype)
    if positions.ndim != 2 or positions.shape[1] != 2:
        raise ValueError(f"positions must have shape (num_cameras, 2); found {positions.shape}")
    n = positions.shape[0]
    dt = positions.dtype
    heights = jnp.zeros(n, dt) if heights is None else jnp.asarray(heights, dt)
    rotvecs = jnp.zeros((n, 3), dt) if rotvecs is None else jnp.asarray(rotvecs, dt)
    if heights.shape != (n,):
        raise ValueError(f"heights must have shape ({n},); found {heights.shape}")
    if rotvecs.shape != (n, 3):
        raise ValueError(f"rotvecs must have shape ({n}, 3); found {rotvecs.shape}")
    return Layout(positions, heights, rotvecs)
