"""Procedural multi-fisheye scenes with exact labels: scenes, ray casting, textures, shading."""

from gijax.render.render import (render_fronto_plane, render_panorama_distance, render_sample,
                                 render_scene, render_views, sample_scene, shade_rays,
                                 trace_distance)
from gijax.render.scene import (FAR, Clearance, Scene, empty_scene, plane_scene, random_scene,
                                rig_clearance, sphere_scene)
from gijax.render.raycast import trace

__all__ = [
    "render_fronto_plane", "render_panorama_distance", "render_sample", "render_scene",
    "render_views", "sample_scene", "shade_rays", "trace_distance", "FAR", "Clearance", "Scene",
    "empty_scene", "plane_scene", "random_scene", "rig_clearance", "sphere_scene", "trace",
]
