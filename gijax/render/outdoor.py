"""Random outdoor scenes: street canyons, trees, poles, overhead slabs and wires under the sky.

Everything is placed around the origin (the rig's reference point) at a random azimuth, which
is the same as a random rig yaw; the ground is a plane below the rig.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from gijax.render.clearance import Clearance
from gijax.render.lighting import random_lighting
from gijax.render.materials import palette_spec
from gijax.render.named_draws import Draws
from gijax.render.scene import NUM_BOXES, NUM_CYLINDERS, Scene, empty_scene

Array = jax.Array

# Slot counts per group; each kind's groups fill its NUM_<KIND> slots exactly.
BUILDINGS, SLABS, NEAR_BOXES, FAR_BLOCKS = 12, 5, 4, 3
TREES, FLOATING, NEAR_SPHERES = 6, 4, 2
POLES, TOWERS = 6, 4
WIRES, GUY_WIRES = 10, 6


def _boxes(d: Draws, clear: Clearance, ground: Array) -> tuple[Array, Array, Array, Array]:
    """Buildings, overhead slabs, small near boxes and far blocks beyond 100 m:
    centres, half extents, yaws and active flags (NUM_BOXES, ...)."""
    b = d.scope("building")
    half_xy = b.uniform("half_xy", (BUILDINGS, 2), 2.0, 14.0)
    # Street canyons: near buildings are tall enough to fill the upward view.
    rho = b.log_uniform("rho", (BUILDINGS,), 4.0, 80.0)
    rho = jnp.maximum(rho, clear.keep + jnp.linalg.norm(half_xy, axis=-1) + 0.3)
    tall = b.log_uniform("height", (BUILDINGS,), 6.0, 90.0)
    buildings = (jnp.concatenate([b.polar("azimuth", (BUILDINGS,), rho),
                                  (ground + tall / 2)[:, None]], -1),
                 jnp.concatenate([half_xy, (tall / 2)[:, None]], -1),
                 b.count_mask("count", BUILDINGS, 6, BUILDINGS))
    s = d.scope("slab")
    s_half = jnp.stack([s.uniform("half_x", (SLABS,), 0.5, 6.0),
                        s.uniform("half_y", (SLABS,), 0.3, 3.0),
                        s.uniform("half_z", (SLABS,), 0.05, 0.5)], -1)
    s_z = clear.top + s.log_uniform("clearance", (SLABS,), 0.3, 12.0) + s_half[:, 2]
    slabs = (jnp.concatenate([s.uniform("xy", (SLABS, 2), -10.0, 10.0), s_z[:, None]], -1),
             s_half, s.count_mask("count", SLABS, 0, SLABS))
    n = d.scope("near_box")
    n_half = n.uniform("half", (NEAR_BOXES, 3), 0.1, 0.8)
    n_rho = (clear.keep + jnp.linalg.norm(n_half[:, :2], axis=-1)
             + n.log_uniform("gap", (NEAR_BOXES,), 0.05, 3.0))
    n_z = n.uniform("z", (NEAR_BOXES,), -1.0, 3.0)
    near = (jnp.concatenate([n.polar("azimuth", (NEAR_BOXES,), n_rho), n_z[:, None]], -1),
            n_half, n.count_mask("count", NEAR_BOXES, 1, NEAR_BOXES))
    f = d.scope("far_block")
    f_half = jnp.stack([f.uniform("half_x", (FAR_BLOCKS,), 20.0, 80.0),
                        f.uniform("half_y", (FAR_BLOCKS,), 10.0, 60.0),
                        f.uniform("half_z", (FAR_BLOCKS,), 20.0, 120.0)], -1)
    f_rho = f.uniform("rho", (FAR_BLOCKS,), 150.0, 400.0)
    far = (jnp.concatenate([f.polar("azimuth", (FAR_BLOCKS,), f_rho),
                            (ground + f_half[:, 2])[:, None]], -1),
           f_half, f.count_mask("count", FAR_BLOCKS, 0, FAR_BLOCKS))
    groups = (buildings, slabs, near, far)
    yaw = d.uniform("box_yaw", (NUM_BOXES,), -math.pi, math.pi)
    return (jnp.concatenate([g[0] for g in groups]), jnp.concatenate([g[1] for g in groups]),
            yaw, jnp.concatenate([g[2] for g in groups]))


def outdoor_scene(d: Draws, clear: Clearance) -> tuple[Scene, Array]:
    """A random outdoor scene around the origin and its palette specs (NUM_PRIMITIVES, 6)."""
    height = d.uniform("height", (), max(1.0, -clear.z_lo + clear.margin + 0.1), 2.2)
    ground = -height
    box_centre, box_half, box_yaw, box_active = _boxes(d, clear, ground)

    # Trees: trunk cylinders with sphere canopies on top; free-floating and near spheres.
    t = d.scope("tree")
    canopy_r = t.uniform("canopy_radius", (TREES,), 1.5, 6.0)
    trunk_r = t.uniform("trunk_radius", (TREES,), 0.08, 0.5)
    trunk_h = t.uniform("trunk_height", (TREES,), 3.0, 12.0)
    t_rho = jnp.maximum(t.log_uniform("rho", (TREES,), 2.0, 40.0), clear.keep + canopy_r + 0.2)
    t_xy = t.polar("azimuth", (TREES,), t_rho)
    tree_on = t.count_mask("count", TREES, 0, TREES)
    canopy_c = jnp.concatenate([t_xy, (ground + trunk_h + 0.6 * canopy_r)[:, None]], -1)
    fl = d.scope("floating")
    fl_r = fl.log_uniform("radius", (FLOATING,), 0.1, 3.0)
    fl_c = jnp.concatenate([fl.polar("azimuth", (FLOATING,),
                                     fl.log_uniform("rho", (FLOATING,), 2.0, 60.0)),
                            fl.uniform("z", (FLOATING, 1), 0.0, 25.0)], -1)
    ns = d.scope("near_sphere")
    ns_r = ns.uniform("radius", (NEAR_SPHERES,), 0.05, 0.4)
    ns_rho = clear.keep + ns_r + ns.uniform("gap", (NEAR_SPHERES,), 0.0, 1.5)
    ns_c = jnp.concatenate([ns.polar("azimuth", (NEAR_SPHERES,), ns_rho),
                            ns.uniform("z", (NEAR_SPHERES, 1), -0.5, 2.0)], -1)
    sphere_centre = jnp.concatenate([canopy_c, fl_c, ns_c])
    sphere_radius = jnp.concatenate([canopy_r, fl_r, ns_r])
    sphere_active = jnp.concatenate([tree_on, fl.count_mask("count", FLOATING, 0, FLOATING),
                                     ns.count_mask("count", NEAR_SPHERES, 0, NEAR_SPHERES)])

    # Cylinders: the trunks, thin poles (one of them close), towers and chimneys far away.
    p = d.scope("pole")
    pole_r = p.uniform("radius", (POLES,), 0.02, 0.15)
    pole_gap = p.log_uniform("gap", (POLES,), 1.0, 40.0)
    pole_gap = pole_gap.at[0].set(p.uniform("near_gap", (), 0.05, 1.5))
    pole_xy = p.polar("azimuth", (POLES,), pole_gap + clear.keep + pole_r)
    pole_top = ground + p.uniform("height", (POLES,), 4.0, 12.0)
    tw = d.scope("tower")
    tw_r = tw.uniform("radius", (TOWERS,), 0.5, 4.0)
    tw_xy = tw.polar("azimuth", (TOWERS,), tw.uniform("rho", (TOWERS,), 20.0, 180.0))
    tw_top = ground + tw.log_uniform("height", (TOWERS,), 10.0, 120.0)
    cylinder_xy = jnp.concatenate([t_xy, pole_xy, tw_xy])
    cylinder_radius = jnp.concatenate([trunk_r, pole_r, tw_r])
    cylinder_z0 = jnp.full((NUM_CYLINDERS,), ground - 0.1)
    cylinder_z1 = jnp.concatenate([ground + trunk_h + 0.2 * canopy_r, pole_top, tw_top])
    poles_on = p.count_mask("count", POLES, 1, POLES)
    cylinder_active = jnp.concatenate([tree_on, poles_on,
                                       tw.count_mask("count", TOWERS, 0, TOWERS)])

    # Capsules: overhead wires (one just above the rig), guy wires from pole tops to the ground.
    w = d.scope("wire")
    w_dir = w.uniform("direction", (WIRES,), -math.pi, math.pi)
    w_u = jnp.stack([jnp.cos(w_dir), jnp.sin(w_dir), w.uniform("slope", (WIRES,), -0.05, 0.05)],
                    -1)
    w_perp = jnp.stack([-jnp.sin(w_dir), jnp.cos(w_dir), jnp.zeros(WIRES)], -1)
    w_off = w.uniform("offset", (WIRES,), -25.0, 25.0)
    w_z = clear.top + w.log_uniform("clearance", (WIRES,), 0.2, 15.0)
    w_z = w_z.at[0].set(clear.top + w.uniform("near_clearance", (), 0.05, 1.0))
    w_mid = w_perp * w_off[:, None] + jnp.stack([jnp.zeros(WIRES), jnp.zeros(WIRES), w_z], -1)
    w_len = w.uniform("length", (WIRES,), 30.0, 160.0)
    g = d.scope("guy_wire")
    g_a = jnp.concatenate([pole_xy, pole_top[:, None]], -1)
    g_foot = g.polar("azimuth", (GUY_WIRES,), g.uniform("reach", (GUY_WIRES,), 2.0, 6.0))
    g_b = jnp.concatenate([pole_xy + g_foot, jnp.full((GUY_WIRES, 1), ground)], -1)
    capsule_a = jnp.concatenate([w_mid - w_u * w_len[:, None] / 2, g_a])
    capsule_b = jnp.concatenate([w_mid + w_u * w_len[:, None] / 2, g_b])
    capsule_radius = jnp.concatenate([w.log_uniform("radius", (WIRES,), 0.004, 0.04),
                                      g.uniform("radius", (GUY_WIRES,), 0.005, 0.02)])
    capsule_active = jnp.concatenate([w.count_mask("count", WIRES, 2, WIRES),
                                      poles_on & g.bernoulli("present", 0.5, (GUY_WIRES,))])

    scene = empty_scene().replace(
        plane_height=jnp.stack([ground, clear.top + 5.0]),
        plane_active=jnp.array([True, False]),
        box_centre=box_centre, box_half=box_half, box_yaw=box_yaw, box_active=box_active,
        sphere_centre=sphere_centre, sphere_radius=sphere_radius, sphere_active=sphere_active,
        cylinder_xy=cylinder_xy, cylinder_radius=cylinder_radius, cylinder_z0=cylinder_z0,
        cylinder_z1=cylinder_z1, cylinder_active=cylinder_active, capsule_a=capsule_a,
        capsule_b=capsule_b, capsule_radius=capsule_radius, capsule_active=capsule_active,
        **random_lighting(d.scope("lighting"), indoor=False))
    spec = jnp.concatenate([
        palette_spec(1, (0.05, 0.35), (0.1, 0.5), (0.25, 0.6)),  # ground
        palette_spec(1, (0.0, 1.0), (0.0, 0.3), (0.4, 0.9)),  # ceiling plane (unused outdoors)
        palette_spec(1, (0.0, 1.0), (0.0, 0.3), (0.4, 0.9)),  # room (unused outdoors)
        palette_spec(BUILDINGS, (0.0, 1.0), (0.0, 0.35), (0.35, 0.95)),
        palette_spec(SLABS, (0.0, 1.0), (0.0, 0.6), (0.3, 0.9)),
        palette_spec(NEAR_BOXES, (0.0, 1.0), (0.3, 0.9), (0.3, 0.95)),
        palette_spec(FAR_BLOCKS, (0.0, 1.0), (0.0, 0.25), (0.4, 0.85)),
        palette_spec(TREES, (0.2, 0.4), (0.35, 0.8), (0.2, 0.65)),  # canopies
        palette_spec(FLOATING + NEAR_SPHERES, (0.0, 1.0), (0.4, 0.9), (0.4, 1.0)),  # balls
        palette_spec(TREES, (0.03, 0.12), (0.3, 0.7), (0.15, 0.45)),  # trunks
        palette_spec(POLES, (0.0, 1.0), (0.0, 0.4), (0.2, 0.8)),
        palette_spec(TOWERS, (0.0, 1.0), (0.0, 0.3), (0.3, 0.85)),
        palette_spec(WIRES + GUY_WIRES, (0.0, 1.0), (0.0, 0.3), (0.05, 0.35)),
    ])
    return scene, spec
