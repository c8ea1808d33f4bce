"""Random indoor scenes: a room (a box seen from inside) with furniture, beams, ducts, shelves,
lamps on cords, balls, columns, pipes and rails.

The room is rotated by a random yaw and shifted so that the rig stands somewhere on its floor
plan; everything is placed in room coordinates and then moved to the rig frame.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from gijax.render.clearance import Clearance, push_out
from gijax.render.lighting import random_lighting
from gijax.render.materials import palette_spec
from gijax.render.named_draws import Draws
from gijax.render.scene import NUM_BOXES, NUM_CYLINDERS, NUM_PLANES, Scene, empty_scene

Array = jax.Array

# Slot counts per group; each kind's groups fill its NUM_<KIND> slots exactly.
FURNITURE, BEAMS, DUCTS, SHELVES = 8, 6, 4, 6
LAMPS, BALLS = 6, 6
COLUMNS, PIPES, STOOLS = 6, 5, 5
CEILING_PIPES, RAILS = 8, 2  # and one cord per lamp


class _Room:
    """Floor plan of the room: half extents, yaw and the rig's offset from the room's centre."""

    def __init__(self, d: Draws, clear: Clearance):
        big = d.bernoulli("big", 0.3)
        half_xy = jnp.where(big, d.uniform("half_xy_big", (2,), 10.0, 35.0),
                            d.uniform("half_xy", (2,), 1.5, 8.0))
        self.half_xy = jnp.maximum(half_xy, clear.keep + 0.3)
        self.ceiling_gap = jnp.where(big, d.uniform("ceiling_gap_big", (), 3.0, 15.0),
                                     d.uniform("ceiling_gap", (), 0.5, 3.5))
        self.yaw = d.uniform("yaw", (), -math.pi, math.pi)
        self.offset = d.uniform("rig_offset", (2,), -1.0, 1.0) * (self.half_xy - clear.keep - 0.2)

    def to_rig(self, xy_room: Array) -> Array:
        """Room-frame horizontal positions (..., 2) -> rig frame."""
        c, s = jnp.cos(self.yaw), jnp.sin(self.yaw)
        return (xy_room - self.offset) @ jnp.array([[c, -s], [s, c]]).T

    def inside(self, d: Draws, name: str, n: int, margin: float) -> Array:
        """``n`` random room-frame positions at least ``margin`` inside the walls."""
        return d.uniform(name, (n, 2), -1.0, 1.0) * (self.half_xy - margin)


def _boxes(d: Draws, room: _Room, clear: Clearance, floor: Array, ceiling: Array):
    """Furniture on the floor, beams under the ceiling, ducts and panels, shelves at the walls:
    centres, half extents, yaws and active flags (NUM_BOXES, ...)."""
    f = d.scope("furniture")
    fur_half = jnp.stack([f.uniform("half_x", (FURNITURE,), 0.2, 1.2),
                          f.uniform("half_y", (FURNITURE,), 0.2, 0.8),
                          f.uniform("half_z", (FURNITURE,), 0.2, 1.3)], -1)
    fur_xy = push_out(room.to_rig(room.inside(f, "xy", FURNITURE, 0.5)),
                      clear.keep + jnp.linalg.norm(fur_half[:, :2], axis=-1) + 0.05)
    fur = (jnp.concatenate([fur_xy, (floor + fur_half[:, 2])[:, None]], -1), fur_half,
           f.count_mask("count", FURNITURE, 2, FURNITURE))
    b = d.scope("beam")
    along_x = b.bernoulli("along_x", 0.5)
    beam_w = b.uniform("half_width", (BEAMS,), 0.08, 0.35)
    beam_d = b.uniform("half_depth", (BEAMS,), 0.1, 0.6)
    beam_pos = b.uniform("position", (BEAMS,), -1.0, 1.0)
    half_xy = room.half_xy
    zeros = jnp.zeros(BEAMS)
    beam_room = jnp.where(along_x, jnp.stack([zeros, beam_pos * half_xy[1]], -1),
                          jnp.stack([beam_pos * half_xy[0], zeros], -1))
    beam_half = jnp.where(along_x, jnp.stack([jnp.full(BEAMS, half_xy[0]), beam_w, beam_d], -1),
                          jnp.stack([beam_w, jnp.full(BEAMS, half_xy[1]), beam_d], -1))
    beams = (jnp.concatenate([room.to_rig(beam_room), (ceiling - beam_half[:, 2])[:, None]], -1),
             beam_half, b.count_mask("count", BEAMS, 0, BEAMS))
    u = d.scope("duct")
    duct_half = jnp.stack([u.uniform("half_x", (DUCTS,), 0.3, 3.0),
                           u.uniform("half_y", (DUCTS,), 0.2, 1.0),
                           u.uniform("half_z", (DUCTS,), 0.05, 0.4)], -1)
    duct_z = ceiling - u.uniform("drop", (DUCTS,), 0.0, 1.5) - duct_half[:, 2]
    ducts = (jnp.concatenate([room.to_rig(room.inside(u, "xy", DUCTS, 0.5)), duct_z[:, None]],
                             -1), duct_half, u.count_mask("count", DUCTS, 0, DUCTS))
    s = d.scope("shelf")
    sh_half = jnp.stack([s.uniform("half_along", (SHELVES,), 0.4, 1.5),
                         s.uniform("half_deep", (SHELVES,), 0.15, 0.4),
                         s.uniform("half_z", (SHELVES,), 0.8, 2.0)], -1)
    # Walls 0 and 1 are at +y and -y, walls 2 and 3 at +x and -x; t is the position along one.
    wall = s.randint("wall", (SHELVES,), 0, 4)
    t = s.uniform("along", (SHELVES,), -0.9, 0.9)
    sh_room = jnp.stack([
        jnp.where(wall < 2, t * half_xy[0], jnp.where(wall == 2, 1.0, -1.0) * (half_xy[0] - 0.4)),
        jnp.where(wall >= 2, t * half_xy[1], jnp.where(wall == 0, 1.0, -1.0) * (half_xy[1] - 0.4)),
    ], -1)
    sh_half = jnp.where((wall >= 2)[:, None], sh_half[:, jnp.array([1, 0, 2])], sh_half)
    shelves = (jnp.concatenate([room.to_rig(sh_room), (floor + sh_half[:, 2])[:, None]], -1),
               sh_half, s.count_mask("count", SHELVES, 0, SHELVES))
    groups = (fur, beams, ducts, shelves)
    # Everything is aligned with the room; furniture stands at a small angle to it.
    yaw = jnp.full((NUM_BOXES,), room.yaw).at[:FURNITURE].add(
        f.uniform("yaw", (FURNITURE,), -0.5, 0.5))
    return (jnp.concatenate([g[0] for g in groups]), jnp.concatenate([g[1] for g in groups]),
            yaw, jnp.concatenate([g[2] for g in groups]))


def indoor_scene(d: Draws, clear: Clearance) -> tuple[Scene, Array]:
    """A random room around the origin and its palette specs (NUM_PRIMITIVES, 6)."""
    height = d.uniform("height", (), max(0.8, -clear.z_lo + clear.margin + 0.1), 2.0)
    floor = -height
    room = _Room(d.scope("room"), clear)
    ceiling = clear.top + room.ceiling_gap
    room_centre = jnp.concatenate([room.to_rig(jnp.zeros(2)), ((floor + ceiling) / 2)[None]])
    room_half = jnp.concatenate([room.half_xy, ((ceiling - floor) / 2)[None]])
    box_centre, box_half, box_yaw, box_active = _boxes(d, room, clear, floor, ceiling)

    # Spheres: hanging lamps (with cords) and balls on the floor.
    la = d.scope("lamp")
    lamp_r = la.uniform("radius", (LAMPS,), 0.08, 0.4)
    lamp_xy = push_out(room.to_rig(room.inside(la, "xy", LAMPS, 0.5)), clear.keep + lamp_r + 0.05)
    lamp_z = ceiling - la.uniform("drop", (LAMPS,), 0.3, 2.5)
    lamp_z = jnp.maximum(lamp_z, floor + lamp_r + 0.5)
    lamp_on = la.count_mask("count", LAMPS, 0, LAMPS)
    ba = d.scope("ball")
    ball_r = ba.uniform("radius", (BALLS,), 0.1, 0.6)
    ball_xy = push_out(room.to_rig(room.inside(ba, "xy", BALLS, 0.6)), clear.keep + ball_r + 0.05)
    sphere_centre = jnp.concatenate([
        jnp.concatenate([lamp_xy, lamp_z[:, None]], -1),
        jnp.concatenate([ball_xy, (floor + ball_r)[:, None]], -1)])
    sphere_radius = jnp.concatenate([lamp_r, ball_r])
    sphere_active = jnp.concatenate([lamp_on, ba.count_mask("count", BALLS, 0, BALLS)])

    # Cylinders: columns floor to ceiling, thin vertical pipes, stools and bins.
    co = d.scope("column")
    col_r = co.uniform("radius", (COLUMNS,), 0.12, 0.6)
    col_xy = push_out(room.to_rig(room.inside(co, "xy", COLUMNS, 0.7)),
                      clear.keep + col_r + co.uniform("gap", (COLUMNS,), 0.0, 1.0))
    vp = d.scope("vertical_pipe")
    pipe_r = vp.uniform("radius", (PIPES,), 0.015, 0.08)
    pipe_xy = push_out(room.to_rig(room.inside(vp, "xy", PIPES, 0.2)), clear.keep + pipe_r + 0.02)
    st = d.scope("stool")
    st_r = st.uniform("radius", (STOOLS,), 0.15, 0.4)
    st_xy = push_out(room.to_rig(room.inside(st, "xy", STOOLS, 0.5)), clear.keep + st_r + 0.02)
    cylinder_xy = jnp.concatenate([col_xy, pipe_xy, st_xy])
    cylinder_radius = jnp.concatenate([col_r, pipe_r, st_r])
    cylinder_z0 = jnp.full((NUM_CYLINDERS,), floor - 0.05)
    cylinder_z1 = jnp.concatenate([jnp.full((COLUMNS + PIPES,), ceiling + 0.05),
                                   floor + st.uniform("height", (STOOLS,), 0.3, 1.0)])
    cylinder_active = jnp.concatenate([co.count_mask("count", COLUMNS, 0, COLUMNS),
                                       vp.count_mask("count", PIPES, 0, PIPES),
                                       st.count_mask("count", STOOLS, 0, STOOLS)])

    # Capsules: pipes along the ceiling from wall to wall, the lamps' cords, slanted rails.
    cp = d.scope("ceiling_pipe")
    pz = ceiling - cp.uniform("drop", (CEILING_PIPES,), 0.05, 0.8)
    p_pos = cp.uniform("position", (CEILING_PIPES,), -1.0, 1.0)
    p_ax = cp.bernoulli("along_x", 0.5, (CEILING_PIPES,))
    hx = jnp.full(CEILING_PIPES, room.half_xy[0])
    hy = jnp.full(CEILING_PIPES, room.half_xy[1])
    pa_room = jnp.where(p_ax[:, None], jnp.stack([-hx, p_pos * hy], -1),
                        jnp.stack([p_pos * hx, -hy], -1))
    pb_room = jnp.where(p_ax[:, None], jnp.stack([hx, p_pos * hy], -1),
                        jnp.stack([p_pos * hx, hy], -1))
    pipe_a = jnp.concatenate([room.to_rig(pa_room), pz[:, None]], -1)
    pipe_b = jnp.concatenate([room.to_rig(pb_room), pz[:, None]], -1)
    cord_a = jnp.concatenate([lamp_xy, (lamp_z + lamp_r)[:, None]], -1)
    cord_b = jnp.concatenate([lamp_xy, jnp.full((LAMPS, 1), ceiling)], -1)
    ra = d.scope("rail")
    rail_a = jnp.concatenate([room.to_rig(room.inside(ra, "foot", RAILS, 0.3)),
                              jnp.full((RAILS, 1), floor)], -1)
    rail_b = jnp.concatenate([room.to_rig(room.inside(ra, "head", RAILS, 0.3)),
                              jnp.full((RAILS, 1), ceiling)], -1)
    capsule_a = jnp.concatenate([pipe_a, cord_a, rail_a])
    capsule_b = jnp.concatenate([pipe_b, cord_b, rail_b])
    capsule_radius = jnp.concatenate([cp.log_uniform("radius", (CEILING_PIPES,), 0.01, 0.15),
                                      la.uniform("cord_radius", (LAMPS,), 0.004, 0.012),
                                      ra.uniform("radius", (RAILS,), 0.02, 0.06)])
    capsule_active = jnp.concatenate([cp.count_mask("count", CEILING_PIPES, 1, CEILING_PIPES),
                                      lamp_on, ra.count_mask("count", RAILS, 0, RAILS)])

    scene = empty_scene().replace(
        plane_height=jnp.stack([floor, ceiling]),
        plane_active=jnp.zeros(NUM_PLANES, bool),
        room_centre=room_centre, room_half=room_half, room_yaw=room.yaw,
        room_active=jnp.asarray(True),
        box_centre=box_centre, box_half=box_half, box_yaw=box_yaw, box_active=box_active,
        sphere_centre=sphere_centre, sphere_radius=sphere_radius, sphere_active=sphere_active,
        cylinder_xy=cylinder_xy, cylinder_radius=cylinder_radius, cylinder_z0=cylinder_z0,
        cylinder_z1=cylinder_z1, cylinder_active=cylinder_active, capsule_a=capsule_a,
        capsule_b=capsule_b, capsule_radius=capsule_radius, capsule_active=capsule_active,
        **random_lighting(d.scope("lighting"), indoor=True))
    spec = jnp.concatenate([
        palette_spec(NUM_PLANES, (0.0, 1.0), (0.0, 0.3), (0.4, 0.9)),  # unused indoors
        palette_spec(1, (0.0, 1.0), (0.0, 0.45), (0.45, 0.95)),  # room walls
        palette_spec(FURNITURE, (0.0, 1.0), (0.2, 0.9), (0.25, 0.95)),
        palette_spec(BEAMS, (0.02, 0.12), (0.2, 0.6), (0.3, 0.85)),
        palette_spec(DUCTS, (0.0, 1.0), (0.0, 0.3), (0.5, 0.95)),
        palette_spec(SHELVES, (0.0, 1.0), (0.2, 0.8), (0.2, 0.9)),
        palette_spec(LAMPS, (0.08, 0.17), (0.0, 0.5), (0.85, 1.0)),
        palette_spec(BALLS, (0.0, 1.0), (0.5, 1.0), (0.5, 1.0)),
        palette_spec(COLUMNS + PIPES + STOOLS, (0.0, 1.0), (0.0, 0.7), (0.2, 0.9)),
        palette_spec(CEILING_PIPES + LAMPS + RAILS, (0.0, 1.0), (0.0, 0.5), (0.1, 0.8)),
    ])
    return scene, spec
