"""Random light and sky: the direction and strength of the sun or lamp, ambient light, sky
colours and cloud cover (the lighting fields of :class:`gijax.render.scene.Scene`)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from gijax.render.materials import hsv_to_rgb
from gijax.render.named_draws import Draws

Array = jax.Array


def random_lighting(d: Draws, indoor: bool) -> dict:
    """Random lighting fields (a dict for :meth:`Scene.replace`) of an indoor or outdoor scene."""
    az = d.uniform("azimuth", (), -math.pi, math.pi)
    # The cameras look up, so light from below the horizon (bounce light, lamps) keeps the
    # downward-facing surfaces they see from being flat.
    el = d.uniform("elevation", (), -0.6, 1.3) if indoor else d.uniform("elevation", (), 0.2, 1.4)
    light = jnp.stack([jnp.cos(el) * jnp.cos(az), jnp.cos(el) * jnp.sin(az), jnp.sin(el)])
    zenith = hsv_to_rgb(d.uniform("zenith/hue", (), 0.53, 0.64),
                        d.uniform("zenith/saturation", (), 0.3, 0.75),
                        d.uniform("zenith/value", (), 0.6, 0.95))
    horizon = hsv_to_rgb(d.uniform("horizon/hue", (), 0.05, 0.6),
                         d.uniform("horizon/saturation", (), 0.0, 0.2),
                         d.uniform("horizon/value", (), 0.8, 1.0))
    return dict(light_dir=light, light_strength=d.uniform("strength", (), 0.35, 0.7),
                ambient=d.uniform("ambient", (), 0.45, 0.7), sky_zenith=zenith,
                sky_horizon=horizon, cloud_freq=d.log_uniform("cloud_freq", (), 2.0, 6.0),
                cloud_cover=d.uniform("cloud_cover", (), 0.1, 0.9))
