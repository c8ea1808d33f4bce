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


def bilinear_sample_zero_padded(image: Array, coords: Array) -> Array:
    """Sample ``image`` (H, W, C) at ``coords`` (..., 2) = (u, v) with zero padding -> (..., C).

    Each of the four neighbours that lies outside the image contributes 0 (its weight is kept,
    its value is 0), so a sample half a pixel outside the last column is half the edge value
    and one at least a pixel outside is 0. These are the semantics of PyTorch's
    ``grid_sample(..., padding_mode='zeros')`` and of torchvision's ``deform_conv2d``, which the
    released network samples its sweep and its spherical taps with; integer (u, v) are pixel
    centres, as everywhere in gijax.
    """
    h, w = image.shape[0], image.shape[1]
    u = coords[..., 0]
    v = coords[..., 1]
    u0 = jnp.floor(u)
    v0 = jnp.floor(v)
    fu = u - u0
    fv = v - v0
    u0 = u0.astype(jnp.int32)
    v0 = v0.astype(jnp.int32)
    flat = image.reshape(h * w, -1)

    def corner(j, i, weight):
        inside = (i >= 0) & (i <= w - 1) & (j >= 0) & (j <= h - 1)
        # Indices are clamped before the gather (same graph under XLA, onnxruntime, TensorRT);
        # the weight of an outside neighbour is zeroed instead.
        idx = jnp.clip(j, 0, h - 1) * w + jnp.clip(i, 0, w - 1)
        return jnp.take(flat, idx, axis=0) * jnp.where(inside, weight, 0.0)[..., None]

    return (corner(v0, u0, (1 - fu) * (1 - fv)) + corner(v0, u0 + 1, fu * (1 - fv))
            + corner(v0 + 1, u0, (1 - fu) * fv) + corner(v0 + 1, u0 + 1, fu * fv))
