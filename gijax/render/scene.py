"""The scene pytree: fixed-size arrays of primitives, so one jit compile serves every seed.

A :class:`Scene` is expressed in the **rig frame** (metres): +z is the rig's viewing axis, which
points up in the world, so the ground is the plane ``z = reference_z - height``.

Primitive kinds and their fixed maximum counts (unused slots have ``active = False``):

* ``NUM_PLANES`` horizontal planes (ground, ceiling), limited to a horizontal range
  ``plane_extent`` from the ray origin (a far horizon).
* one room: an axis-aligned box rotated about +z, seen from inside (walls, floor, ceiling).
* ``NUM_BOXES`` solid boxes rotated about +z (buildings, furniture, beams, slabs).
* ``NUM_SPHERES`` spheres (tree canopies, lamps, balls).
* ``NUM_CYLINDERS`` vertical capped cylinders (trunks, columns, thin poles).
* ``NUM_CAPSULES`` capsules around a segment (wires, pipes, cords, branches).

Every primitive has a material (row ``OFFSET_<KIND> + k`` of the ``mat_*`` arrays): a three-colour
palette, a solid-noise frequency and a stripe/check pattern evaluated at the 3D hit point, so the
texture of a surface point is the same from every viewpoint (see :mod:`gijax.render.texture`).

Random scenes are made by :mod:`gijax.render.random_scene`; this module holds the type and the
hand-built scenes that tests and calibration targets use.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

Array = jax.Array

NUM_PLANES = 2
NUM_BOXES = 24
NUM_SPHERES = 12
NUM_CYLINDERS = 16
NUM_CAPSULES = 16
OFFSET_PLANES = 0
OFFSET_ROOM = OFFSET_PLANES + NUM_PLANES
OFFSET_BOXES = OFFSET_ROOM + 1
OFFSET_SPHERES = OFFSET_BOXES + NUM_BOXES
OFFSET_CYLINDERS = OFFSET_SPHERES + NUM_SPHERES
OFFSET_CAPSULES = OFFSET_CYLINDERS + NUM_CYLINDERS
NUM_PRIMITIVES = OFFSET_CAPSULES + NUM_CAPSULES
SKY_ID = -1
# Horizontal range of the ground plane: rays grazing the ground further out see the sky.
PLANE_EXTENT = 5000.0
# Pattern kinds of a material.
PATTERN_NONE, PATTERN_STRIPES, PATTERN_CHECKS = 0, 1, 2


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Scene:
    """Primitives, materials, light and sky of one scene (all leaves; shapes fixed, see module)."""

    plane_height: Array  # (NUM_PLANES,) z of each horizontal plane, rig frame
    plane_active: Array  # (NUM_PLANES,) bool
    plane_extent: Array  # () horizontal range of the planes, metres
    room_centre: Array  # (3,)
    room_half: Array  # (3,) half extents
    room_yaw: Array  # () rotation about +z, radians
    room_active: Array  # () bool
    box_centre: Array  # (NUM_BOXES, 3)
    box_half: Array  # (NUM_BOXES, 3)
    box_yaw: Array  # (NUM_BOXES,)
    box_active: Array  # (NUM_BOXES,)
    sphere_centre: Array  # (NUM_SPHERES, 3)
    sphere_radius: Array  # (NUM_SPHERES,)
    sphere_active: Array
    cylinder_xy: Array  # (NUM_CYLINDERS, 2) axis position
    cylinder_radius: Array  # (NUM_CYLINDERS,)
    cylinder_z0: Array  # (NUM_CYLINDERS,) bottom
    cylinder_z1: Array  # (NUM_CYLINDERS,) top
    cylinder_active: Array
    capsule_a: Array  # (NUM_CAPSULES, 3) segment start
    capsule_b: Array  # (NUM_CAPSULES, 3) segment end
    capsule_radius: Array  # (NUM_CAPSULES,)
    capsule_active: Array
    mat_colours: Array  # (NUM_PRIMITIVES, 3, 3) palette, RGB in [0, 1]
    mat_noise_freq: Array  # (NUM_PRIMITIVES,) base noise frequency, cycles per metre
    mat_pattern: Array  # (NUM_PRIMITIVES,) int32 PATTERN_*
    mat_pattern_freq: Array  # (NUM_PRIMITIVES,) cycles per metre
    mat_pattern_axis: Array  # (NUM_PRIMITIVES, 3) unit stripe normal
    mat_pattern_strength: Array  # (NUM_PRIMITIVES,) in [0, 1]
    mat_offset: Array  # (NUM_PRIMITIVES, 3) noise-space offset (decorrelates primitives)
    light_dir: Array  # (3,) unit vector towards the light
    light_strength: Array  # ()
    ambient: Array  # ()
    sky_zenith: Array  # (3,) RGB
    sky_horizon: Array  # (3,) RGB
    cloud_freq: Array  # () cycles per radian
    cloud_cover: Array  # () in [0, 1]

    def replace(self, **kw) -> "Scene":
        return dataclasses.replace(self, **kw)


def _f(x) -> Array:
    return jnp.asarray(x, jnp.float32)


def empty_scene() -> Scene:
    """A scene with nothing in it (every ray sees the sky); base for hand-built test scenes."""
    z3 = jnp.zeros(3, jnp.float32)
    p = NUM_PRIMITIVES
    grey = jnp.tile(jnp.array([[0.5, 0.5, 0.5], [0.3, 0.3, 0.3], [0.8, 0.8, 0.8]],
                              jnp.float32), (p, 1, 1))
    return Scene(
        plane_height=jnp.zeros(NUM_PLANES, jnp.float32),
        plane_active=jnp.zeros(NUM_PLANES, bool), plane_extent=_f(PLANE_EXTENT),
        room_centre=z3, room_half=jnp.ones(3, jnp.float32), room_yaw=_f(0.0),
        room_active=jnp.asarray(False),
        box_centre=jnp.zeros((NUM_BOXES, 3), jnp.float32),
        box_half=jnp.ones((NUM_BOXES, 3), jnp.float32), box_yaw=jnp.zeros(NUM_BOXES, jnp.float32),
        box_active=jnp.zeros(NUM_BOXES, bool),
        sphere_centre=jnp.zeros((NUM_SPHERES, 3), jnp.float32),
        sphere_radius=jnp.ones(NUM_SPHERES, jnp.float32),
        sphere_active=jnp.zeros(NUM_SPHERES, bool),
        cylinder_xy=jnp.zeros((NUM_CYLINDERS, 2), jnp.float32),
        cylinder_radius=jnp.ones(NUM_CYLINDERS, jnp.float32),
        cylinder_z0=jnp.zeros(NUM_CYLINDERS, jnp.float32),
        cylinder_z1=jnp.ones(NUM_CYLINDERS, jnp.float32),
        cylinder_active=jnp.zeros(NUM_CYLINDERS, bool),
        capsule_a=jnp.zeros((NUM_CAPSULES, 3), jnp.float32),
        capsule_b=jnp.ones((NUM_CAPSULES, 3), jnp.float32),
        capsule_radius=jnp.ones(NUM_CAPSULES, jnp.float32),
        capsule_active=jnp.zeros(NUM_CAPSULES, bool),
        mat_colours=grey, mat_noise_freq=jnp.ones(p, jnp.float32),
        mat_pattern=jnp.zeros(p, jnp.int32), mat_pattern_freq=jnp.ones(p, jnp.float32),
        mat_pattern_axis=jnp.tile(jnp.array([0.0, 0.0, 1.0], jnp.float32), (p, 1)),
        mat_pattern_strength=jnp.zeros(p, jnp.float32), mat_offset=jnp.zeros((p, 3), jnp.float32),
        light_dir=jnp.array([0.3, 0.2, 0.93], jnp.float32) / jnp.linalg.norm(
            jnp.array([0.3, 0.2, 0.93])),
        light_strength=_f(0.6), ambient=_f(0.5),
        sky_zenith=jnp.array([0.35, 0.55, 0.9], jnp.float32),
        sky_horizon=jnp.array([0.8, 0.85, 0.92], jnp.float32), cloud_freq=_f(3.0),
        cloud_cover=_f(0.4),
    )


def sphere_scene(centre, radius) -> Scene:
    """Only one sphere (slot 0) of ``radius`` metres around ``centre`` (3,), plain grey."""
    scene = empty_scene()
    return scene.replace(
        sphere_centre=scene.sphere_centre.at[0].set(jnp.asarray(centre, jnp.float32)),
        sphere_radius=scene.sphere_radius.at[0].set(_f(radius)),
        sphere_active=scene.sphere_active.at[0].set(True))


def plane_scene(height, extent: float = PLANE_EXTENT) -> Scene:
    """Only a horizontal plane at z = ``height`` (rig frame), e.g. the ground below the rig."""
    scene = empty_scene()
    return scene.replace(plane_height=scene.plane_height.at[0].set(_f(height)),
                         plane_active=scene.plane_active.at[0].set(True),
                         plane_extent=_f(extent))


def translate(scene: Scene, offset: Array) -> Scene:
    """The primitives moved by ``offset`` (3,) metres (textures stay put: they are looked up at
    the hit point)."""
    return scene.replace(
        plane_height=scene.plane_height + offset[2], room_centre=scene.room_centre + offset,
        box_centre=scene.box_centre + offset, sphere_centre=scene.sphere_centre + offset,
        cylinder_xy=scene.cylinder_xy + offset[:2], cylinder_z0=scene.cylinder_z0 + offset[2],
        cylinder_z1=scene.cylinder_z1 + offset[2], capsule_a=scene.capsule_a + offset,
        capsule_b=scene.capsule_b + offset)
