"""Procedural multi-fisheye scenes with exact labels: scenes, ray casting, textures, shading.

The maths are pure functions of a scene and a PRNG key (:mod:`gijax.render.views`,
:func:`random_scene`); :func:`render_sample` and its siblings take integer seeds and return
numpy arrays for the dataset writer.
"""

from gijax.geometry.occluder import FAR
from gijax.render.clearance import Clearance, rig_clearance
from gijax.render.random_scene import SCENE_VERSION, random_scene, textured_sphere
from gijax.render.raycast import trace
from gijax.render.render import (render_fronto_plane, render_sample, render_scene,
                                 sample_scene)
from gijax.render.scene import Scene, empty_scene, plane_scene, sphere_scene
from gijax.render.views import (random_sample, random_sample_scene, render_panorama_distance,
                                render_views, trace_distance)

__all__ = [
    "SCENE_VERSION",
    "render_fronto_plane", "render_panorama_distance", "render_sample", "render_scene",
    "render_views", "sample_scene", "trace_distance", "FAR", "Clearance", "Scene",
    "empty_scene", "plane_scene", "random_scene", "rig_clearance", "sphere_scene", "trace",
    "random_sample", "random_sample_scene", "textured_sphere",
]
