"""The renderer's edge: integer seeds in, numpy arrays out.

The maths are the pure functions of :mod:`gijax.render.views` on a PRNG key; this module turns a
non-negative integer ``seed`` into the sample's key (``jax.random.PRNGKey(seed)``), checks the
arguments and converts the device arrays to the dtypes stored on disk (uint8 images and masks,
float32 distances). The same seed always gives the same sample.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import Rig
from gijax.render import views
from gijax.render.random_scene import STYLE_CHOICES, STYLES, is_indoor, textured_sphere
from gijax.render.scene import Scene
from gijax.render.views import DEFAULT_CHUNK


def _key(seed: int) -> jax.Array:
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer; found {seed!r}")
    return jax.random.PRNGKey(int(seed))


def _to_numpy(out: dict) -> dict:
    def u8(x):
        return np.round(np.clip(np.asarray(x), 0.0, 1.0) * 255.0).astype(np.uint8)

    conv = dict(images=u8, distances=lambda x: np.asarray(x, np.float32),
                masks=lambda x: np.asarray(x).astype(np.uint8),
                pano_distance=lambda x: np.asarray(x, np.float32))
    res = {}
    for k, f in conv.items():
        v = out[k]
        res[k] = [f(a) for a in v] if isinstance(v, list) else f(v)
    return res


def choose_style(seed: int, style: str) -> str:
    """The scene style of ``seed``: ``style`` itself, or the sample's named draw when 'mixed'."""
    if style not in STYLE_CHOICES:
        raise ValueError(f"unknown style {style!r}; expected one of {STYLE_CHOICES}")
    scene_key, _ = views.sample_keys(_key(seed))
    return STYLES[0] if bool(is_indoor(scene_key, style)) else STYLES[1]


def sample_scene(rig: Rig, seed: int, style: str = "mixed") -> Scene:
    """The random scene of ``seed`` around ``rig`` (clear of its cameras and body by 0.5 m)."""
    return views.random_sample_scene(rig, _key(seed), style)


def render_scene(rig: Rig, scene: Scene, seed: int, pano: Panorama = Panorama.hemisphere(160, 640),
                 noise: bool = True, chunk: int = DEFAULT_CHUNK) -> dict:
    """Render a given scene; numpy outputs as :func:`render_sample` (``seed`` drives the
    per-camera exposure and sensor noise)."""
    _, views_key = views.sample_keys(_key(seed))
    return _to_numpy(views.render_views(scene, rig, views_key, pano, chunk, noise))


def render_sample(rig: Rig, seed: int, pano: Panorama = Panorama.hemisphere(160, 640),
                  style: str = "mixed", noise: bool = True, chunk: int = DEFAULT_CHUNK) -> dict:
    """One random training sample for ``rig``, deterministic from ``seed``.

    Returns numpy arrays: ``images`` uint8 (N, h, w, 3) RGB, ``distances`` float32 (N, h, w)
    metres along each pixel's ray (1e6 for sky and outside the lens), ``masks`` uint8 (N, h, w)
    (1 = sees the world), ``pano_distance`` float32 (H, W) metres from the reference point along
    each ray of ``pano`` (1e6 for sky; the rig's body is not in it). ``style`` is 'indoor',
    'outdoor' or 'mixed' (a seeded pick). ``noise=False`` leaves out the sensor noise. The
    device-array version for a PRNG key is :func:`gijax.render.views.random_sample`.
    """
    if style not in STYLE_CHOICES:
        raise ValueError(f"unknown style {style!r}; expected one of {STYLE_CHOICES}")
    return _to_numpy(views.random_sample(rig, _key(seed), pano, style, noise, chunk))


def render_fronto_plane(rig: Rig, distance: float, seed: int,
                        pano: Panorama = Panorama.hemisphere(160, 640)) -> dict:
    """A textured sphere of radius ``distance`` metres centred on the rig's reference point.

    Every panorama ray reads exactly ``distance``; outputs as :func:`render_sample`. The sphere
    must enclose every camera centre.
    """
    ref = np.asarray(rig.reference, np.float64)
    reach = float(np.max(np.linalg.norm(np.asarray(rig.translations, np.float64) - ref, axis=-1)))
    if not (math.isfinite(distance) and distance > reach):
        raise ValueError(f"distance must exceed the largest camera distance from the reference "
                         f"point ({reach:.4f} m); found {distance}")
    scene_key, _ = views.sample_keys(_key(seed))
    scene = textured_sphere(jnp.asarray(rig.reference, jnp.float32), distance, scene_key)
    return render_scene(rig, scene, seed, pano)
