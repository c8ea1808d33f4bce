"""View-independent solid textures: colour as a function of the 3D hit point and the material.

Because the colour of a surface point depends only on where it is (and on which primitive it
belongs to), every camera sees the same texture on the same point, so multi-view matching is well
posed. Detail comes from multi-octave value noise (a hashed integer lattice with smooth
trilinear interpolation) plus stripes or 3D checks at a second scale, warped by the noise.

Octaves finer than the pixel footprint (metres per pixel at the hit) fade to their mean, which
is what a mip-mapped renderer does; it suppresses aliasing without changing the texture's
coarser content, which stays identical across views.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

Array = jax.Array
NOISE_OCTAVES = 5
GRAIN_OCTAVES = 3


def _hash3(ix: Array, iy: Array, iz: Array) -> Array:
    """Integer lattice coordinates (int32) -> pseudo-random values in [0, 1) (float32)."""
    u = lambda a: jax.lax.bitcast_convert_type(a, jnp.uint32)  # noqa: E731
    h = u(ix) * jnp.uint32(0x8DA6B343) ^ u(iy) * jnp.uint32(0xD8163841) ^ u(iz) * jnp.uint32(
        0xCB1AB31F)
    h = (h ^ (h >> 16)) * jnp.uint32(0x7FEB352D)
    h = (h ^ (h >> 15)) * jnp.uint32(0x846CA68B)
    h = h ^ (h >> 16)
    return (h >> 8).astype(jnp.float32) * (1.0 / 16777216.0)


_CORNERS = np.array([[dx, dy, dz] for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)], np.int32)


def value_noise(p: Array) -> Array:
    """Smooth value noise of points (M, 3) in lattice units -> (M,) in [0, 1].

    The 8 lattice corners are hashed as one (M, 8) batch and blended with smoothstep weights.
    """
    fl = jnp.floor(p)
    f = p - fl
    s = f * f * (3.0 - 2.0 * f)
    corners = fl.astype(jnp.int32)[:, None, :] + _CORNERS
    h = _hash3(corners[..., 0], corners[..., 1], corners[..., 2])
    w = jnp.where(_CORNERS == 1, s[:, None, :], 1.0 - s[:, None, :])
    return jnp.sum(h * w[..., 0] * w[..., 1] * w[..., 2], -1)


def _fade(freq: Array, footprint: Array) -> Array:
    """Weight of a feature of ``freq`` cycles/m at ``footprint`` m/pixel: 1 when it spans 4+
    pixels, 0 when it spans 2 or fewer."""
    return jnp.clip((0.5 - freq * footprint) / 0.25, 0.0, 1.0)


def fbm(p: Array, freq: Array, footprint: Array, octaves: int, gain: float = 0.65) -> Array:
    """Fractal sum of ``octaves`` value-noise octaves from ``freq`` (M,) cycles/m up, each
    doubling; points (M, 3) in metres. Returns (M,) around 0.5 (roughly [0, 1])."""
    shift = jnp.array([17.3, -41.1, 7.7], p.dtype)

    def octave(k, carry):
        total, amp, f = carry
        # A fixed shift per octave decorrelates the octaves' lattices.
        n = value_noise(p * f[:, None] + shift * k.astype(p.dtype))
        return total + amp * _fade(f, footprint) * (n - 0.5), amp * gain, f * 2.0

    total, _, _ = jax.lax.fori_loop(
        0, octaves, octave, (jnp.zeros(p.shape[0], p.dtype), jnp.asarray(1.0, p.dtype), freq))
    norm = sum(gain**k for k in range(octaves))
    return 0.5 + total / norm * 1.6


def _smoothstep(lo, hi, x):
    t = jnp.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def albedo(p: Array, mat: dict, footprint: Array) -> Array:
    """Surface colour (M, 3) in [0, 1] of world points ``p`` (M, 3) with per-ray material fields.

    ``mat`` holds per-ray rows gathered from the scene's ``mat_*`` arrays: colours (M, 3, 3),
    noise_freq (M,), pattern (M,) int, pattern_freq (M,), pattern_axis (M, 3),
    pattern_strength (M,), offset (M, 3). ``footprint`` (M,) is metres per pixel at the hit.
    """
    q = p + mat["offset"]
    n1 = fbm(q, mat["noise_freq"], footprint, NOISE_OCTAVES)
    c0, c1, c2 = mat["colours"][:, 0], mat["colours"][:, 1], mat["colours"][:, 2]
    colour = c0 + (c1 - c0) * _smoothstep(0.3, 0.7, n1)[:, None]
    pf = mat["pattern_freq"]
    warp = 0.6 * (n1 - 0.5)
    stripes = 0.5 + 0.5 * jnp.sin(2.0 * jnp.pi * (pf * jnp.sum(p * mat["pattern_axis"], -1)
                                                  + warp))
    stripes = jnp.clip((stripes - 0.5) * 3.0 + 0.5, 0.0, 1.0)
    w = jnp.sin(jnp.pi * (pf[:, None] * p + warp[:, None]))
    checks = jnp.clip(0.5 + 3.0 * w[:, 0] * w[:, 1] * w[:, 2], 0.0, 1.0)
    pat = jnp.where(mat["pattern"] == 1, stripes, checks)
    pat = 0.5 + (pat - 0.5) * _fade(pf, footprint)
    strength = jnp.where(mat["pattern"] == 0, 0.0, mat["pattern_strength"])
    colour = colour + (c2 - colour) * (strength * pat)[:, None]
    # Fine grain from four times the base frequency up: the detail that pins down matches.
    grain = fbm(q * 1.37, mat["noise_freq"] * 4.0, footprint, GRAIN_OCTAVES)
    colour = colour * (0.55 + 0.9 * grain)[:, None]
    return jnp.clip(colour, 0.0, 1.0)


def sky(d: Array, scene, footprint_angle: Array) -> Array:
    """Sky colour (M, 3) of unit directions ``d`` (M, 3): zenith/horizon gradient and clouds.

    A function of direction only (the sky is at infinity), so it is identical in every camera.
    ``footprint_angle`` (M,) is radians per pixel.
    """
    up = jnp.clip(d[:, 2], 0.0, 1.0)
    base = scene.sky_horizon + (scene.sky_zenith - scene.sky_horizon) * jnp.sqrt(up)[:, None]
    f = jnp.full(d.shape[:1], scene.cloud_freq)
    # Clouds live on a plane high above: stretch the direction by 1/elevation like a dome.
    dome = d / (0.25 + up)[:, None]
    c = fbm(dome + 100.0, f, footprint_angle / (0.25 + up), 4)
    lo = 0.75 - 0.5 * scene.cloud_cover
    cloud = _smoothstep(lo, lo + 0.25, c)
    colour = base + (jnp.array([0.96, 0.96, 0.97]) * (0.8 + 0.3 * c)[:, None] - base) * (
        0.9 * cloud)[:, None]
    below = d[:, 2] < 0.0
    return jnp.where(below[:, None], scene.sky_horizon * 0.7, jnp.clip(colour, 0.0, 1.0))
