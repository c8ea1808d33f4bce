"""Bilinear sampling by an explicit 4-neighbour gather.

Indices are clamped *before* the gather and an explicit validity mask zeroes samples outside the
image, rather than relying on out-of-bounds gather semantics: the same graph then behaves
identically under XLA, onnxruntime and TensorRT (which has no 5-D GridSample before 11.2), and
it is differentiable with respect to both the image and the sampling coordinates.

Pixel convention: integer (u, v) are pixel centres (see :mod:`gijax.geometry.cameras`). A sample
is valid when (u, v) lies in [0, W - 1] x [0, H - 1] (all four neighbours exist); samples within
half a pixel outside that range are clamped to the edge and still count as valid, so that the
whole image [-0.5, W - 0.5] samples without holes.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

Array = jax.Array


def bilinear_sample(image: Array, coords: Array, valid: Array | None = None) -> tuple[Array, Array]:
    """Sample ``image`` (H, W, C) at ``coords`` (..., 2) = (u, v) -> (..., C), validity (...).

    Samples outside [-0.5, W - 0.5] x [-0.5, H - 0.5], or where ``valid`` is False, are 0.
    """
    h, w = image.shape[0], image.shape[1]
    u = coords[..., 0]
    v = coords[..., 1]
    inside = (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)
    if valid is not None:
        inside = inside & valid
    u = jnp.clip(u, 0.0, w - 1.0)
    v = jnp.clip(v, 0.0, h - 1.0)
    u0 = jnp.floor(u)
    v0 = jnp.floor(v)
    fu = (u - u0)[..., None]
    fv = (v - v0)[..., None]
    # Clamp the integer indices before gathering (x1 may step one past the last column).
    i0 = jnp.clip(u0.astype(jnp.int32), 0, w - 1)
    j0 = jnp.clip(v0.astype(jnp.int32), 0, h - 1)
    i1 = jnp.minimum(i0 + 1, w - 1)
    j1 = jnp.minimum(j0 + 1, h - 1)
    flat = image.reshape(h * w, -1)

    def take(j, i):
        return jnp.take(flat, j * w + i, axis=0)

    top = take(j0, i0) * (1 - fu) + take(j0, i1) * fu
    bottom = take(j1, i0) * (1 - fu) + take(j1, i1) * fu
    out = top * (1 - fv) + bottom * fv
    return jnp.where(inside[..., None], out, 0.0), inside
