"""Linear x2 upsampling along chosen axes (bilinear, trilinear), align_corners=False semantics.

Output sample ``o`` along an axis of length ``n`` sits at source coordinate ``(o + 0.5) / 2 - 0.5``
(pixel centres at integers, as in PyTorch's ``interpolate(..., align_corners=False)`` and
``jax.image.resize(..., 'linear')``). For x2 that gives fixed weights:

* even ``o = 2k``:  source ``k - 0.25`` -> ``0.75 x[k] + 0.25 x[k-1]``
* odd ``o = 2k+1``: source ``k + 0.25`` -> ``0.75 x[k] + 0.25 x[k+1]``

with the neighbour clamped to the edge at both ends (a source coordinate below 0 or above
``n - 1`` clamps, so the first and last outputs copy the edge sample).

Written with slices, concatenations, multiplies and a reshape only: it lowers to Slice / Concat /
Mul / Add / Reshape in ONNX, which every TensorRT version accepts, whereas ``jax.image.resize``
lowers to dense interpolation-matrix dot products (one per axis) whose cost grows with the square
of the axis length.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp

Array = jax.Array


def upsample2_axis(x: Array, axis: int) -> Array:
    """Linear x2 upsampling of ``x`` along ``axis`` (length n -> 2n), align_corners=False."""
    axis = axis % x.ndim
    n = x.shape[axis]

    def take(start, stop):
        return jax.lax.slice_in_dim(x, start, stop, axis=axis)

    if n == 1:
        prev = nxt = x
    else:
        prev = jnp.concatenate([take(0, 1), take(0, n - 1)], axis=axis)
        nxt = jnp.concatenate([take(1, n), take(n - 1, n)], axis=axis)
    even = 0.75 * x + 0.25 * prev
    odd = 0.75 * x + 0.25 * nxt
    # Interleave: stack on a new axis right after `axis`, then merge the two.
    out = jnp.stack([even, odd], axis=axis + 1)
    shape = list(x.shape)
    shape[axis] = 2 * n
    return out.reshape(shape)


def upsample2(x: Array, axes: Sequence[int]) -> Array:
    """Separable linear x2 upsampling along every axis in ``axes`` (e.g. (1, 2, 3) = trilinear
    for a (B, D, h, w, C) volume; (2, 3) = bilinear for (B, D, h, w) logits)."""
    for axis in axes:
        x = upsample2_axis(x, axis)
    return x
