"""The rig's own body: a capped vertical cylinder (the paper's LiDAR) in the rig frame.

The cylinder's axis is parallel to the rig's viewing axis (+z); it occupies
``z_min <= z <= z_max`` around the axis through ``(x, y)`` with the given radius.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from gijax.numerics import away_from_zero, safe_div, safe_sqrt

Array = jax.Array
FAR = 1e6  # distance reported for "no hit" (the sky convention of the dataset)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Cylinder:
    x: Array
    y: Array
    radius: Array
    z_min: Array
    z_max: Array


def cylinder_intersection(cyl: Cylinder, origins: Array, dirs: Array,
                          t_min: float = 0.0) -> tuple[Array, Array]:
    """First hit beyond ``t_min`` of the rays ``origins + t dirs`` (unit ``dirs``) on the
    cylinder's surface: the distance ``t`` (``FAR`` on a miss) and the unit normal there.

    The side wall counts where a ray enters it from outside, the caps from either side. Normals
    point out of the cylinder (caps: -z at ``z_min``, +z at ``z_max``); on a miss the normal is
    meaningless. Broadcasts over leading shapes. The side's discriminant is computed from the
    ray's horizontal miss distance, ``a r^2 - ((o - axis) x d)_z^2``, rather than as
    ``b^2 - 4ac``: no cancellation, so centimetre-thin cylinders stay exact at 100 m in float32.
    Traceable, with finite gradients everywhere (exact wherever the hit keeps its surface).
    """
    ox = origins[..., 0] - cyl.x
    oy = origins[..., 1] - cyl.y
    oz = origins[..., 2]
    dx, dy, dz = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    a = dx * dx + dy * dy
    b = ox * dx + oy * dy
    cross = ox * dy - oy * dx
    disc = a * cyl.radius**2 - cross * cross
    # The nearer root, where the ray enters the infinite cylinder.
    t_side = safe_div(-b - safe_sqrt(disc), a)
    z_side = oz + t_side * dz
    side_ok = ((disc >= 0.0) & (a > 1e-12) & (t_side > t_min) & (z_side >= cyl.z_min)
               & (z_side <= cyl.z_max))
    t = jnp.where(side_ok, t_side, FAR)
    normal = jnp.stack([ox + t_side * dx, oy + t_side * dy, jnp.zeros_like(dx)], -1) / cyl.radius
    dz_safe = away_from_zero(dz)
    for zc, outward in ((cyl.z_min, -1.0), (cyl.z_max, 1.0)):
        t_cap = (zc - oz) / dz_safe
        px = ox + t_cap * dx
        py = oy + t_cap * dy
        cap_ok = (t_cap > t_min) & (px * px + py * py <= cyl.radius**2) & (t_cap < t)
        t = jnp.where(cap_ok, t_cap, t)
        normal = jnp.where(cap_ok[..., None], jnp.array([0.0, 0.0, outward], normal.dtype),
                           normal)
    return t, normal


def cylinder_hit(cyl: Cylinder, origins: Array, dirs: Array) -> Array:
    """Distance along unit ``dirs`` from ``origins`` to the first hit of the capped cylinder.

    Returns ``FAR`` where the ray misses. Broadcasts over leading shapes. Origins inside the
    cylinder report a hit at distance 0. Traceable; the distance is differentiable in the
    origins, directions and the cylinder wherever the hit does not switch surfaces.
    """
    t, _ = cylinder_intersection(cyl, origins, dirs)
    ox = origins[..., 0] - cyl.x
    oy = origins[..., 1] - cyl.y
    oz = origins[..., 2]
    inside = (ox * ox + oy * oy <= cyl.radius**2) & (oz >= cyl.z_min) & (oz <= cyl.z_max)
    return jnp.where(inside, 0.0, t)
