"""The rig's keep-out zone: random scenes leave a margin around the cameras and the rig's body.

Scenes are generated around the rig's reference point (the origin here); the zone is a vertical
cylinder around it that holds every camera centre and the body, inflated by a margin. Labels
nearer than the margin would fall below the nearest candidate distance, and a surface through a
camera centre would make its image meaningless.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from gijax.numerics import safe_norm, unit
from gijax.render.scene import Scene

Array = jax.Array


@dataclasses.dataclass(frozen=True)
class Clearance:
    """The rig's keep-out zone relative to its reference point, metres.

    No primitive comes within ``margin`` of the cylinder of radius ``radius`` spanning
    ``z_lo..z_hi`` that holds every camera centre and the rig's body (plain floats, so a
    clearance is a static argument of the jitted generator).
    """

    radius: float
    z_lo: float
    z_hi: float
    margin: float = 0.5

    @property
    def keep(self) -> float:
        """Horizontal distance from the axis that objects must stay beyond."""
        return self.radius + self.margin

    @property
    def top(self) -> float:
        """Height above which objects may pass over the rig."""
        return self.z_hi + self.margin


def rig_clearance(rig, margin: float = 0.5) -> Clearance:
    """The keep-out cylinder of a :class:`gijax.geometry.rig.Rig` around its reference point."""
    ref = np.asarray(rig.reference, np.float64)
    t = np.asarray(rig.translations, np.float64) - ref
    radius = float(np.max(np.hypot(t[:, 0], t[:, 1])))
    z_lo, z_hi = float(t[:, 2].min()), float(t[:, 2].max())
    occ = rig.occluder
    if occ is not None:
        ox, oy = float(occ.x) - ref[0], float(occ.y) - ref[1]
        radius = max(radius, math.hypot(ox, oy) + float(occ.radius))
        z_lo = min(z_lo, float(occ.z_min) - ref[2])
        z_hi = max(z_hi, float(occ.z_max) - ref[2])
    return Clearance(radius, z_lo, z_hi, margin)


def push_out(xy: Array, min_rho: Array) -> Array:
    """Move horizontal positions (..., 2) radially out to at least ``min_rho`` from the axis.

    A position on the axis itself goes out along +x.
    """
    rho = safe_norm(xy, keepdims=True)
    direction = jnp.where(rho > 1e-6, unit(xy), jnp.array([1.0, 0.0]))
    return jnp.where(rho < min_rho[..., None], direction * min_rho[..., None], xy)


def _violates(rho, reach, z_min, z_max, clear: Clearance) -> Array:
    """True where an object of horizontal reach ``reach`` around a centre at horizontal
    distance ``rho`` spanning ``z_min..z_max`` enters the inflated keep-out cylinder."""
    near_xy = rho - reach < clear.keep
    near_z = (z_max > clear.z_lo - clear.margin) & (z_min < clear.top)
    return near_xy & near_z


def _capsule_violates(a: Array, b: Array, r: Array, clear: Clearance) -> Array:
    """True for capsules with any of 65 spheres along their segment inside the zone."""
    s = jnp.linspace(0.0, 1.0, 65)
    pts = a[:, None] + s[None, :, None] * (b - a)[:, None]
    rho = safe_norm(pts[..., :2])
    bad = _violates(rho, r[:, None], pts[..., 2] - r[:, None], pts[..., 2] + r[:, None], clear)
    return jnp.any(bad, -1)


def enforce_clearance(scene: Scene, clear: Clearance) -> Scene:
    """Deactivate every primitive that still reaches into the rig's inflated keep-out zone.

    Generators place objects outside the zone already; this is the guarantee for the ones whose
    placement could not account for every extent (rotated boxes, slanted capsules).
    """
    bx_rho = safe_norm(scene.box_centre[:, :2])
    bad_box = _violates(bx_rho, safe_norm(scene.box_half[:, :2]),
                        scene.box_centre[:, 2] - scene.box_half[:, 2],
                        scene.box_centre[:, 2] + scene.box_half[:, 2], clear)
    sp_rho = safe_norm(scene.sphere_centre[:, :2])
    bad_sp = _violates(sp_rho, scene.sphere_radius, scene.sphere_centre[:, 2] - scene.sphere_radius,
                       scene.sphere_centre[:, 2] + scene.sphere_radius, clear)
    cy_rho = safe_norm(scene.cylinder_xy)
    bad_cy = _violates(cy_rho, scene.cylinder_radius, scene.cylinder_z0, scene.cylinder_z1, clear)
    bad_ca = _capsule_violates(scene.capsule_a, scene.capsule_b, scene.capsule_radius, clear)
    return scene.replace(box_active=scene.box_active & ~bad_box,
                         sphere_active=scene.sphere_active & ~bad_sp,
                         cylinder_active=scene.cylinder_active & ~bad_cy,
                         capsule_active=scene.capsule_active & ~bad_ca)
