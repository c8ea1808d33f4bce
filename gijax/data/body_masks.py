"""Random rig-body outlines entering a fisheye from its border, as validity masks.

A real rig's arms, legs, propellers and sensors occlude a fisheye from the edge of its image
circle inwards with smooth, irregular outlines that a rendered rig (one cylinder) never shows.
A body here is a smooth star-shaped blob: in a frame centred at ``centre`` and turned so that
its first axis points away from the image centre, a point ``q`` (scaled by the semi-axes) is
inside when ``|q| < 1 + sum_k c_k cos(k angle(q) + phase_k)``, k = 2..4 (low orders only, so
the outline stays smooth). Centred near the image circle, it covers a bite of the border.

Pure and traceable: the outline is drawn from a PRNG key.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

Array = jax.Array

ORDERS = (2, 3, 4)


@dataclasses.dataclass(frozen=True)
class BodyShape:
    """Ranges of the random outline (fractions of the image circle radius, half the shorter
    image side): the blob's centre lies ``distance`` from the image centre, its semi-axes are
    ``radial`` (towards the image centre) and ``tangential`` (along the border), and each
    outline harmonic has amplitude up to ``wobble``."""

    distance: tuple = (0.9, 1.1)
    radial: tuple = (0.2, 0.5)
    tangential: tuple = (0.2, 0.6)
    wobble: float = 0.12


def body_outline(key: Array, shape: BodyShape = BodyShape()) -> dict:
    """The random parameters of one outline (see :func:`body_occlusion`)."""
    k = jax.random.split(key, 6)
    u = lambda kk, lo_hi: jax.random.uniform(kk, (), jnp.float32, *lo_hi)  # noqa: E731
    return {"direction": jax.random.uniform(k[0], (), jnp.float32, -jnp.pi, jnp.pi),
            "distance": u(k[1], shape.distance), "radial": u(k[2], shape.radial),
            "tangential": u(k[3], shape.tangential),
            "amplitude": jax.random.uniform(k[4], (len(ORDERS),), jnp.float32,
                                            -shape.wobble, shape.wobble),
            "phase": jax.random.uniform(k[5], (len(ORDERS),), jnp.float32, -jnp.pi, jnp.pi)}


def body_occlusion(height: int, width: int, centre, outline: dict) -> Array:
    """(H, W) float32: 1 where the body outline covers the pixel centre, else 0.

    ``centre`` (u, v) is the image centre the outline is placed around (the principal point);
    lengths in ``outline`` are fractions of half the shorter image side.
    """
    scale = 0.5 * min(height, width)
    v = jnp.arange(height, dtype=jnp.float32)[:, None]
    u = jnp.arange(width, dtype=jnp.float32)[None, :]
    c, s = jnp.cos(outline["direction"]), jnp.sin(outline["direction"])
    centre = jnp.asarray(centre, jnp.float32)
    du = u - (centre[0] + c * outline["distance"] * scale)
    dv = v - (centre[1] + s * outline["distance"] * scale)
    # Coordinates along (radial) and across (tangential) the direction, in semi-axis units.
    a = (c * du + s * dv) / (outline["radial"] * scale)
    b = (-s * du + c * dv) / (outline["tangential"] * scale)
    angle = jnp.arctan2(b, a)
    orders = jnp.asarray(ORDERS, jnp.float32)
    edge = 1.0 + jnp.sum(outline["amplitude"]
                         * jnp.cos(orders * angle[..., None] + outline["phase"]), -1)
    return (jnp.hypot(a, b) < edge).astype(jnp.float32)
