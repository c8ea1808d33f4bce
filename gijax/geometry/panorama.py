"""Equirectangular panoramas: ray grids and direction <-> pixel maps, both ways, any size.

A panorama is described by its size and its latitude range. Directions are expressed in the
panorama's own frame, whose +z axis is its pole (for the rig panorama: the frame that
:mod:`gijax.geometry.panorama_frame` places in the rig, by default the rig's viewing axis; for a
per-camera surrogate image: that camera's optical axis).

* Polar angle ``theta`` from +z; latitude ``lat = theta - 90 deg``. The paper's hemisphere runs
  from lat = -90 deg (row 0 edge, the pole, on the axis) to lat = 0 deg (the horizon of the
  rig plane); the full sphere runs from -90 to +90 deg. Row 0 is the pole: the top of the image.
* Longitude ``lon = atan2(-y, x)`` in [-180, 180) deg, column 0 edge at -180 deg, 0 deg (the
  +x axis) in the middle column. This is the common equirectangular layout: seen from the
  centre with the pole up, the column grows to the right (a viewer facing +x with +z up has -y
  on the right hand). It is the layout of the release's panoramas (longitude ``atan2(x, z)`` in
  a frame whose -y axis is the pole), and the image is not mirrored.
* Pixel centres follow the image convention of :mod:`gijax.geometry.cameras`: pixel (col, row)
  has its centre at lon = -pi + (col + 0.5) * 2 pi / W, lat = lat0 + (row + 0.5) * (lat1 - lat0) / H.

Every function is traceable (jit, vmap, grad in the directions and pixels); a
:class:`Panorama` is static.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp

from gijax.numerics import guard_floor, safe_sqrt

Array = jax.Array


@dataclasses.dataclass(frozen=True)
class Panorama:
    """Size and latitude range (radians) of an equirectangular image; hashable, static."""

    height: int
    width: int
    lat_min: float = -math.pi / 2
    lat_max: float = 0.0

    @classmethod
    def hemisphere(cls, height: int = 160, width: int = 640) -> "Panorama":
        """The paper's hemisphere: latitude -90..0 deg (pole on the viewing axis)."""
        return cls(height, width, -math.pi / 2, 0.0)

    @classmethod
    def sphere(cls, height: int = 320, width: int = 640) -> "Panorama":
        """The full sphere: latitude -90..90 deg."""
        return cls(height, width, -math.pi / 2, math.pi / 2)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)


def lonlat_grid(pano: Panorama, dtype=jnp.float32) -> tuple[Array, Array]:
    """(H, W) longitude and latitude of every pixel centre, radians."""
    col = (jnp.arange(pano.width, dtype=dtype) + 0.5) / pano.width
    row = (jnp.arange(pano.height, dtype=dtype) + 0.5) / pano.height
    lon = -jnp.pi + 2.0 * jnp.pi * col
    lat = pano.lat_min + (pano.lat_max - pano.lat_min) * row
    lon, lat = jnp.meshgrid(lon, lat, indexing="xy")
    return lon, lat


def lonlat_to_direction(lon: Array, lat: Array) -> Array:
    """Unit direction (..., 3); lat = -90 deg is +z (the pole), lat = 0 the x-y plane, lon = 0
    the +x axis and lon = +90 deg the -y axis (see the module docstring)."""
    theta = lat + jnp.pi / 2
    s = jnp.sin(theta)
    return jnp.stack([s * jnp.cos(lon), -s * jnp.sin(lon), jnp.cos(theta)], axis=-1)


def direction_to_lonlat(d: Array) -> tuple[Array, Array]:
    """Inverse of :func:`lonlat_to_direction` (direction need not be unit length).

    On the pole (``x = y = 0``) the longitude is 0 with a zero gradient (``atan2`` has none
    there).
    """
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    sq = x * x + y * y
    on_pole = sq <= guard_floor(sq)
    lon = jnp.arctan2(jnp.where(on_pole, 0.0, -y), jnp.where(on_pole, 1.0, x))
    theta = jnp.arctan2(safe_sqrt(sq), z)
    return lon, theta - jnp.pi / 2


def ray_grid(pano: Panorama, dtype=jnp.float32) -> Array:
    """(H, W, 3) unit directions of every panorama pixel centre."""
    lon, lat = lonlat_grid(pano, dtype)
    return lonlat_to_direction(lon, lat)


def direction_to_pixel(pano: Panorama, d: Array) -> tuple[Array, Array]:
    """Pixel (col, row) of directions (..., 3) and whether they fall inside the latitude range.

    Longitude wraps: col is in [-0.5, W - 0.5).
    """
    lon, lat = direction_to_lonlat(d)
    col = (lon + jnp.pi) / (2 * jnp.pi) * pano.width - 0.5
    row = (lat - pano.lat_min) / (pano.lat_max - pano.lat_min) * pano.height - 0.5
    valid = (lat >= pano.lat_min - 1e-7) & (lat <= pano.lat_max + 1e-7)
    return jnp.stack([col, row], axis=-1), valid


def pixel_to_direction(pano: Panorama, px: Array) -> Array:
    """Unit direction of pixel coordinates (..., 2) = (col, row)."""
    lon = -jnp.pi + 2 * jnp.pi * (px[..., 0] + 0.5) / pano.width
    lat = pano.lat_min + (pano.lat_max - pano.lat_min) * (px[..., 1] + 0.5) / pano.height
    return lonlat_to_direction(lon, lat)
