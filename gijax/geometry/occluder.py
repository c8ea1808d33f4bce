"""The rig's own body: a capped vertical cylinder (the paper's LiDAR) in the rig frame.

The cylinder's axis is parallel to the rig's viewing axis (+z); it occupies
``z_min <= z <= z_max`` around the axis through ``(x, y)`` with the given radius.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

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


def cylinder_hit(cyl: Cylinder, origins: Array, dirs: Array) -> Array:
    """Distance along unit ``dirs`` from ``origins`` to the first hit of the capped cylinder.

    Returns ``FAR`` where the ray misses. Broadcasts over leading shapes. Origins inside the
    cylinder report a hit at distance 0.
    """
    ox = origins[..., 0] - cyl.x
    oy = origins[..., 1] - cyl.y
    oz = origins[..., 2]
    dx, dy, dz = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    a = dx * dx + dy * dy
    b = 2.0 * (ox * dx + oy * dy)
    c = ox * ox + oy * oy - cyl.radius**2
    disc = b * b - 4.0 * a * c
    has = (disc >= 0.0) & (a > 1e-12)
    sq = jnp.sqrt(jnp.where(has, disc, 0.0))
    a_safe = jnp.where(a > 1e-12, a, 1.0)
    t_side = (-b - sq) / (2.0 * a_safe)
    t_side = jnp.where(t_side < 0.0, (-b + sq) / (2.0 * a_safe), t_side)
    z_side = oz + t_side * dz
    side_ok = has & (t_side >= 0.0) & (z_side >= cyl.z_min) & (z_side <= cyl.z_max)
    t_hit = jnp.where(side_ok, t_side, FAR)
    dz_safe = jnp.where(jnp.abs(dz) > 1e-12, dz, 1.0)
    for zc in (cyl.z_min, cyl.z_max):
        t_cap = (zc - oz) / dz_safe
        px = ox + t_cap * dx
        py = oy + t_cap * dy
        cap_ok = (jnp.abs(dz) > 1e-12) & (t_cap >= 0.0) & (px * px + py * py <= cyl.radius**2)
        t_hit = jnp.where(cap_ok & (t_cap < t_hit), t_cap, t_hit)
    inside = (c <= 0.0) & (oz >= cyl.z_min) & (oz <= cyl.z_max)
    return jnp.where(inside, 0.0, t_hit)
