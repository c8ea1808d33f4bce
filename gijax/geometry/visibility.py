"""Which points of a surface a viewpoint sees: a z-buffer over directions.

A panorama's distance map describes the surfaces seen from the rig's reference point. A
camera elsewhere on the rig sees the same surfaces from another place, and some of the
panorama's points are hidden from it behind nearer ones (a post 1 m in front of a wall hides
a different strip of the wall from each camera). A comparison of the cameras' colours at such
a point compares the wall with the post.

:func:`visible_from` finds those points from the points themselves: their directions from the
viewpoint are binned on the pixels of a ``width // 2`` x ``width`` spherical panorama
(:class:`gijax.geometry.panorama.Panorama`'s longitude and latitude, its pole on ``+z``: bins
shrink towards the pole as a panorama's own pixels do), the nearest point of each bin
is kept (the largest inverse distance, a scatter-max), and a point is visible when its inverse
distance is within ``margin`` (relative) of its bin's nearest. The margin lets a surface that
is slanted within one bin count as seen; a point farther than that behind a nearer point in its
direction is hidden. Bins no point falls in hide nothing, so a hidden point whose occluder
has too few points to cover its bin stays visible (the test errs towards seeing).

Pure (a function of the points and the viewpoint; jit- and vmap-able). Its output is a step
function of the inputs, so its gradient is zero; the inputs are read through
``stop_gradient``, which keeps forward-mode derivatives from carrying tangents through the
scatter.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from gijax.geometry.panorama import Panorama, direction_to_pixel

Array = jax.Array

# The default margin (relative, in inverse distance). Across one bin (1.9 degrees at 192 bins)
# a surface turned up to about 55 degrees from facing the viewpoint changes its inverse
# distance by less than this, while a post at 1 m before a wall at 3 m differs by 67 %.
OCCLUSION_MARGIN = 0.05


def visible_from(points: Array, centre: Array, width: int,
                 margin: float = OCCLUSION_MARGIN) -> Array:
    """1 where the viewpoint ``centre`` (3,) sees ``points`` (..., 3), 0 where a nearer point
    of the same set in the same direction hides it (see the module docstring).

    Args:
      points: (..., 3) metres, in the frame of ``centre``.
      centre: (3,) the viewpoint.
      width: bins over 360 degrees of longitude (static); about the points' own angular
        spacing as seen from ``centre`` (a panorama's width for its own points).
      margin: how much farther than its bin's nearest point (relative, in inverse distance) a
        point may be and still count as seen.

    Returns (...) in ``points``' dtype.
    """
    pts = jax.lax.stop_gradient(points)
    v = pts - jax.lax.stop_gradient(centre).astype(pts.dtype)
    inv = 1.0 / jnp.maximum(jnp.sqrt(jnp.sum(v * v, -1)), jnp.finfo(pts.dtype).tiny)
    grid = Panorama.sphere(width // 2, width)
    px, _ = direction_to_pixel(grid, v)
    # Pixel centres sit at integer coordinates: a bin is the pixel whose centre is nearest.
    col = jnp.mod(jnp.floor(px[..., 0] + 0.5), width).astype(jnp.int32)
    row = jnp.clip(jnp.floor(px[..., 1] + 0.5), 0, grid.height - 1).astype(jnp.int32)
    nearest = jnp.zeros(grid.shape, pts.dtype).at[row, col].max(inv)
    return (inv >= nearest[row, col] * (1.0 - margin)).astype(pts.dtype)
