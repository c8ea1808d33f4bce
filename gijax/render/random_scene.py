"""Random scenes as pure functions of a PRNG key: indoor rooms and outdoor streets, textured.

Every random number is a named draw (:mod:`gijax.render.named_draws`) of the scene's key, so a
change to one part of a generator (a new object, a new material parameter) leaves the rest of
every seed's scene as it was.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from gijax.numerics import safe_div, safe_norm
from gijax.render.clearance import Clearance, enforce_clearance
from gijax.render.indoor import indoor_scene
from gijax.render.materials import palette_spec, random_materials
from gijax.render.named_draws import Draws, named_uniform, run_with_draws
from gijax.render.outdoor import outdoor_scene
from gijax.render.scene import NUM_PRIMITIVES, Scene, sphere_scene, translate

Array = jax.Array
# The version of what a seed renders to. Datasets record it, so resuming a dataset made by
# another version is refused instead of mixing two generations of scenes. 2: named draws;
# 3: panorama longitude in the common equirectangular direction (labels mirrored from 2).
SCENE_VERSION = 3
STYLES = ("indoor", "outdoor")
STYLE_CHOICES = STYLES + ("mixed",)


def is_indoor(key: Array, style: str) -> Array:
    """() bool: whether the scene of ``key`` is a room. 'mixed' makes it a fair named draw."""
    if style not in STYLE_CHOICES:
        raise ValueError(f"unknown scene style {style!r}; expected one of {STYLE_CHOICES}")
    if style == "mixed":
        return named_uniform(key, "style") < 0.5
    return jnp.asarray(style == "indoor")


def _segment_distance(a: Array, b: Array) -> Array:
    """Distance (K,) of segments a-b (K, 3) to the origin."""
    ba = b - a
    s = jnp.clip(safe_div(-jnp.sum(a * ba, -1), jnp.sum(ba * ba, -1)), 0.0, 1.0)
    return safe_norm(a + s[:, None] * ba)


def primitive_distances(scene: Scene) -> Array:
    """(P,) rough distance of each primitive from the origin, at least 0.5 m (texture scale)."""
    # The cameras see the ground beyond roughly 7 times its depth (under a 195 deg lens).
    planes = jnp.abs(scene.plane_height) * jnp.array([6.0, 1.0])
    room = jnp.min(scene.room_half)[None]
    boxes = jnp.maximum(safe_norm(scene.box_centre) - safe_norm(scene.box_half),
                        0.5 + 0.3 * jnp.min(scene.box_half, -1))
    spheres = safe_norm(scene.sphere_centre) - scene.sphere_radius
    cyl = safe_norm(scene.cylinder_xy) - scene.cylinder_radius
    caps = _segment_distance(scene.capsule_a, scene.capsule_b) - scene.capsule_radius
    return jnp.maximum(jnp.concatenate([planes, room, boxes, spheres, cyl, caps]), 0.5)


def scene_program(d: Draws, indoor: Array, clearance: Clearance) -> Scene:
    """The random scene around the origin that the draws ``d`` describe.

    Both generators run and ``indoor`` picks one, so a single compile serves both styles; each
    draws under its own names, so neither changes the other's numbers.
    """
    s_in, spec_in = indoor_scene(d.scope("indoor"), clearance)
    s_out, spec_out = outdoor_scene(d.scope("outdoor"), clearance)
    scene = jax.tree_util.tree_map(lambda a, b: jnp.where(indoor, a, b), s_in, s_out)
    spec = jnp.where(indoor, spec_in, spec_out)
    scene = enforce_clearance(scene, clearance)
    return scene.replace(**random_materials(d.scope("materials"), primitive_distances(scene),
                                            spec))


def random_scene(key: Array, style: str, clearance: Clearance, reference) -> Scene:
    """A random scene around ``reference`` (3,) in the rig frame, a pure function of ``key``.

    ``style`` is 'indoor', 'outdoor' or 'mixed' (a named draw of ``key``, see
    :func:`is_indoor`). Nothing comes within ``clearance.margin`` metres of the rig's keep-out
    cylinder (see :func:`gijax.render.clearance.rig_clearance`). Jit-able in ``key`` and
    ``reference``; one compile per clearance serves every key and style.
    """
    return _random_scene(key, is_indoor(key, style), clearance,
                         jnp.asarray(reference, jnp.float32))


@functools.partial(jax.jit, static_argnames=("clearance",))
def _random_scene(key: Array, indoor: Array, clearance: Clearance, reference: Array) -> Scene:
    scene = run_with_draws(key, lambda d: scene_program(d, indoor, clearance))
    return translate(scene, reference)


@jax.jit
def textured_sphere(centre, radius, key: Array) -> Scene:
    """:func:`gijax.render.scene.sphere_scene` with a random material drawn from ``key``."""
    dist = jnp.full((NUM_PRIMITIVES,), jnp.asarray(radius, jnp.float32))
    spec = palette_spec(NUM_PRIMITIVES, (0.0, 1.0), (0.1, 0.8), (0.25, 0.9))
    materials = run_with_draws(key, lambda d: random_materials(d.scope("materials"), dist, spec))
    return sphere_scene(centre, radius).replace(**materials)
