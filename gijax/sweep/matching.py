"""The classical matching cost as a cost-volume channel: how well the cameras agree in colour on
each (candidate, cost cell) point.

A learned cost volume built from 8-channel features at a 5.6-degree cell has to rediscover what
the classical baseline measures directly on the images (:mod:`gijax.baseline.matching_cost`):
that at the right distance every camera sees the same texture. :func:`cell_zncc` gives the
network that measure: per cost cell and candidate, the cameras' grey levels at the ``k x k``
sub-cell points of the cell (:func:`gijax.sweep.grids.match_grids`, read from the surrogate
images, i.e. at up to ``k`` times the cost volume's resolution) form one patch per camera, and
the cue is the mean zero-mean normalised cross-correlation over every pair of cameras that see
the whole cell.

Unlike the baseline's ZNCC, the patch is the cost cell's own footprint on the panorama, sampled
at the sub-cell centres, rather than a window of the matching view around every pixel; it
correlates grey levels (the mean of the three channels) rather than the pooled colour channels,
which keeps the sampled data a third of the size (the cue costs memory bandwidth, not
arithmetic); and all cameras are compared with each other (a consensus, independent of the
camera order and count, like the variance cost volume) rather than a reference with one chosen
partner. An offset or gain of a camera's grey level that is constant over a cell cancels.

Pure, traceable and differentiable (with respect to the colours, and through them to the grids
and the rig): the pooled norms are regularised by ``eps`` per sample, so textureless patches
tend to a correlation of 0 (the "uncorrelated" value) with finite gradients, instead of 0 / 0.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

Array = jax.Array

# Per pooled sample, the variance (colours in [0, 1]) below which a patch counts as textureless:
# a grey-level spread of 1 % (2.5 of 255 levels) leaves correlations at half their value.
TEXTURE_EPS = 1e-4


def _small_sum(x: Array, axis: int) -> Array:
    """Sum of ``x`` over a short static ``axis`` as a chain of slice additions.

    Why not ``jnp.sum``: jaxlib 0.10's CPU backend hands small reductions to YNNPACK "reduce"
    fusions, which are slow on the camera axis and on the cell's sample rows; written as
    additions they fuse elementwise (the ZNCC of a training batch, 8 x 3 cameras x 16
    candidates x 64 x 256 points: 147 ms as sums, 48 ms so; the values differ only by the
    order of the additions). Exported, the slices and additions are plain ONNX nodes.
    """
    parts = [jax.lax.index_in_dim(x, i, axis, keepdims=False) for i in range(x.shape[axis])]
    total = parts[0]
    for part in parts[1:]:
        total = total + part
    return total


def cell_zncc(grey: Array, seen: Array, samples: int, eps: float = TEXTURE_EPS) -> Array:
    """Mean pairwise ZNCC of the cameras' cell patches (B, D, h, w), in [-1, 1].

    Args:
      grey: (B, N, D, k h, k w) the cameras' grey levels at the sub-cell points of every
        (candidate, cost cell) (:func:`gijax.sweep.grids.match_grey`).
      seen: (B, N, D, k h, k w) > 0 where the camera sees the point.
      samples: ``k``, sub-cells per cell side.
      eps: per-sample variance that regularises the patch norms (:data:`TEXTURE_EPS`).

    A camera takes part in a cell when it sees all ``k x k`` of its points. With ``z_i`` camera
    i's centred patch divided by ``sqrt(|z|^2 + eps k^2)``, the mean over the ``V (V - 1) / 2``
    pairs of taking-part cameras is ``(|sum_i z_i|^2 - sum_i |z_i|^2) / (V (V - 1))``; 0 where
    fewer than two cameras take part. The same numbers as :func:`cell_zncc_batch_last` on the
    batch-last layout, which the network uses.
    """
    if tuple(seen.shape) != tuple(grey.shape):
        raise ValueError(f"seen must have the grey levels' shape {tuple(grey.shape)}; found "
                         f"{tuple(seen.shape)}")
    ncc = cell_zncc_batch_last(jnp.moveaxis(grey, 0, -1), jnp.moveaxis(seen, 0, -1), samples,
                               eps)
    return jnp.moveaxis(ncc, -1, 0)


def cell_zncc_batch_last(grey: Array, seen: Array, samples: int,
                         eps: float = TEXTURE_EPS) -> Array:
    """:func:`cell_zncc` with the batch as the last axis: grey levels and ``seen`` (N, D, k h,
    k w, B) -> (D, h, w, B).

    The layout the batched sampler of :func:`gijax.sweep.grids.match_grey` (``batch_last``)
    gathers in, so the network never transposes the sub-cell samples (16 times the size of
    the result) between the gather and this arithmetic.
    """
    n, d, hh, ww, b = grey.shape
    k = samples
    if hh % k or ww % k:
        raise ValueError(f"sub-cell values of {hh} x {ww} points do not split into cells of "
                         f"{k} x {k}")
    if tuple(seen.shape) != tuple(grey.shape):
        raise ValueError(f"seen must have the grey levels' shape {tuple(grey.shape)}; found "
                         f"{tuple(seen.shape)}")
    h, w = hh // k, ww // k
    size = k * k
    dtype = grey.dtype

    def cell_sum(v):          # (N, D h, k, w, k, B) -> (N, D h, w, B)
        # Within a row of the cell a reduction; the k rows, whole contiguous blocks, added.
        return _small_sum(jnp.sum(v, axis=4), 2)

    # Reshapes only (no copy): cell rows on axis 1 (candidate-major), the cell's own samples on
    # axes 2 and 4. Few axes on purpose: XLA's CPU backend (jaxlib 0.10) crashes executing some
    # fused reductions of 8-axis arrays.
    x = grey.reshape(n, d * h, k, w, k, b)
    points = cell_sum((seen > 0).astype(dtype).reshape(n, d * h, k, w, k, b))
    part = (points > size - 0.5).astype(dtype)                   # (N, D h, w, B): all seen
    mean = cell_sum(x) * (1.0 / size)
    centred = x - mean[:, :, None, :, None]
    sq = cell_sum(centred * centred)                             # (N, D h, w, B)
    scale = jax.lax.rsqrt(sq + eps * size) * part                # 0 for cameras left out
    unit = centred * scale[:, :, None, :, None]
    # Left-out cameras have unit = 0, so they add nothing to either camera sum.
    total = _small_sum(unit, 0)                                   # (D h, k, w, k, B)
    own = _small_sum(sq * scale * scale, 0)                       # (D h, w, B)
    count = _small_sum(part, 0)
    pairs2 = count * (count - 1.0)                               # twice the pair count
    ncc = (_small_sum(jnp.sum(total * total, axis=3), 1) - own) / jnp.maximum(pairs2, 1.0)
    return jnp.where(count >= 2.0, ncc, 0.0).reshape(d, h, w, b)
