"""Simple shading and per-camera sensor effects.

Shading is Lambertian with one directional light, a dimmer fill from the opposite side and a
hemispherical ambient term; it depends on the surface normal only, never on the viewer, so the
same surface point has the same radiance in every camera. Per-camera differences (exposure gain,
white balance, vignetting, sensor noise) are applied afterwards, as a real rig's sensors would.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

Array = jax.Array
RIG_BODY_GREY = 0.14


def shade(colour: Array, normal: Array, d: Array, light_dir: Array, strength: Array,
          ambient: Array) -> Array:
    """Radiance (M, 3) of albedo ``colour`` (M, 3) with unit ``normal`` (M, 3) hit by rays ``d``.

    Normals are turned to face the incoming ray (surfaces are two-sided).
    """
    facing = jnp.where(jnp.sum(normal * d, -1, keepdims=True) > 0.0, -normal, normal)
    ndl = jnp.sum(facing * light_dir, -1)
    light = (ambient * (0.85 + 0.15 * facing[:, 2]) + strength * jnp.maximum(ndl, 0.0)
             + 0.2 * strength * jnp.maximum(-ndl, 0.0))
    return colour * light[:, None]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Exposure:
    """Per-camera sensor settings (leading camera axis N on every field)."""

    gain: Array  # (N,) exposure multiplier
    tint: Array  # (N, 3) white-balance multipliers
    vignette: Array  # (N,) relative fall-off at the rim of the field of view
    noise_std: Array  # (N,) Gaussian noise standard deviation on [0, 1] colours


def random_exposure(key: Array, n: int) -> Exposure:
    """Exposure for ``n`` cameras: gain 0.75-1.25, tint within 7 %, vignetting up to 35 %,
    noise 0.004-0.02 (one uniform draw split into the fields)."""
    u = jax.random.uniform(key, (n, 6))
    return Exposure(gain=0.75 + 0.5 * u[:, 0], tint=0.93 + 0.14 * u[:, 1:4],
                    vignette=0.35 * u[:, 4], noise_std=0.004 + 0.016 * u[:, 5])


def expose(radiance: Array, exposure: Exposure, cam_id: Array, rim: Array, key: Array,
           noise: bool = True) -> Array:
    """Colours in [0, 1] from radiance (M, 3) of pixels of cameras ``cam_id`` (M,) int; ``rim``
    (M,) is the angle from the optical axis relative to half the field of view (0 centre, 1
    rim)."""
    c = radiance * exposure.gain[cam_id][:, None] * exposure.tint[cam_id]
    c = c * (1.0 - exposure.vignette[cam_id] * jnp.clip(rim, 0.0, 1.0) ** 2)[:, None]
    if noise:
        c = c + exposure.noise_std[cam_id][:, None] * jax.random.normal(key, c.shape, c.dtype)
    return jnp.clip(c, 0.0, 1.0)
