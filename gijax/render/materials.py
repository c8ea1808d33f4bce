"""Random materials: per-primitive palettes, noise scales and stripe or check patterns.

A material is a row of the scene's ``mat_*`` arrays (see :class:`gijax.render.scene.Scene`);
:mod:`gijax.render.texture` turns it into a colour at a 3D hit point. A generator describes
what each primitive may look like with a *palette spec*, a row (6,) of hue range, saturation
range and value range (HSV, all in [0, 1]); :func:`random_materials` draws the rest.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from gijax.numerics import unit
from gijax.render.named_draws import Draws
from gijax.render.scene import NUM_PRIMITIVES, PATTERN_CHECKS, PATTERN_NONE, PATTERN_STRIPES

Array = jax.Array


def hsv_to_rgb(h: Array, s: Array, v: Array) -> Array:
    """Vectorised HSV (all in [0, 1]) to RGB (..., 3)."""
    k = jnp.stack([5.0, 3.0, 1.0])
    kk = jnp.mod(k + h[..., None] * 6.0, 6.0)
    return v[..., None] - v[..., None] * s[..., None] * jnp.clip(jnp.minimum(kk, 4.0 - kk), 0, 1)


def palette_spec(n: int, hue, sat, val) -> Array:
    """(n, 6) palette spec rows: ``hue``, ``sat`` and ``val`` are (lo, hi) ranges."""
    return jnp.tile(jnp.array([*hue, *sat, *val], jnp.float32), (n, 1))


def random_materials(d: Draws, distance: Array, spec: Array) -> dict:
    """Random ``mat_*`` fields (a dict for :meth:`Scene.replace`) of every primitive.

    ``distance`` (P,) is each primitive's distance from the reference point (metres) and sets
    the base noise frequency so that texture detail starts at a few pixels wide on screen near
    and far; ``spec`` (P, 6) is each primitive's palette spec (:func:`palette_spec`).
    """
    p = NUM_PRIMITIVES
    hue = d.uniform("hue", (p,)) * (spec[:, 1] - spec[:, 0]) + spec[:, 0]
    sat = d.uniform("saturation", (p,)) * (spec[:, 3] - spec[:, 2]) + spec[:, 2]
    val = d.uniform("value", (p,)) * (spec[:, 5] - spec[:, 4]) + spec[:, 4]
    # Three colours: the base, a darker shade of a nearby hue, and a free accent colour.
    c0 = hsv_to_rgb(jnp.mod(hue, 1.0), sat, val)
    hue1 = jnp.mod(hue + d.uniform("shade/hue_shift", (p,), -0.08, 0.08), 1.0)
    val1 = jnp.clip(val * d.uniform("shade/darkening", (p,), 0.35, 0.75), 0.03, 1.0)
    c1 = hsv_to_rgb(hue1, jnp.clip(sat * 1.2, 0, 1), val1)
    hue2 = jnp.mod(hue + d.uniform("accent/hue_shift", (p,), -0.5, 0.5), 1.0)
    c2 = hsv_to_rgb(hue2, d.uniform("accent/saturation", (p,), 0.05, 0.8),
                    d.uniform("accent/value", (p,), 0.15, 0.95))
    freq = d.log_uniform("noise_cycles", (p,), 3.0, 10.0) / jnp.maximum(distance, 0.5)
    pick = d("pattern", (p,))
    pattern = jnp.where(pick > 0.65, PATTERN_CHECKS,
                        jnp.where(pick > 0.3, PATTERN_STRIPES, PATTERN_NONE)).astype(jnp.int32)
    pattern_freq = freq * d.log_uniform("pattern_scale", (p,), 0.7, 4.0)
    # Half the stripes run horizontally (like courses of bricks or floors of a building).
    horizontal = d.bernoulli("pattern_horizontal", 0.5, (p,))
    axis = jnp.where(horizontal[:, None], jnp.array([0.0, 0.0, 1.0]),
                     unit(d.normal("pattern_axis", (p, 3))))
    return dict(mat_colours=jnp.stack([c0, c1, c2], 1), mat_noise_freq=freq, mat_pattern=pattern,
                mat_pattern_freq=pattern_freq, mat_pattern_axis=axis,
                mat_pattern_strength=d.uniform("pattern_strength", (p,), 0.35, 0.9),
                mat_offset=d.uniform("noise_offset", (p, 3), -1000.0, 1000.0))
