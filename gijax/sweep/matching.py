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
    fewer than two cameras take part.
    """
    b, n, d, hh, ww = grey.shape
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
    # Reshapes only (no copy): cell rows on axis 2 (candidate-major), the cell's own samples on
    # axes 3 and 5. Few axes on purpose: XLA's CPU backend (jaxlib 0.10) crashes executing some
    # fused reductions of 8-axis arrays.
    # Sums only, no mean or min: the ONNX export's opset (17) takes ReduceSum's axes as an input
    # but ReduceMean's and ReduceMin's as attributes, which jax2onnx does not write.
    x = grey.reshape(b, n, d * h, k, w, k)
    points = jnp.sum((seen > 0).astype(dtype).reshape(b, n, d * h, k, w, k), axis=(3, 5))
    part = (points > size - 0.5).astype(dtype)                   # (B, N, D h, w): all seen
    mean = jnp.sum(x, axis=(3, 5), keepdims=True) * (1.0 / size)
    centred = x - mean
    sq = jnp.sum(centred * centred, axis=(3, 5))                 # (B, N, D h, w)
    scale = jax.lax.rsqrt(sq + eps * size) * part                # 0 for cameras left out
    unit = centred * scale[:, :, :, None, :, None]
    # Left-out cameras have unit = 0, so they add nothing to either camera sum.
    total = jnp.sum(unit, axis=1)                                # (B, D h, k, w, k)
    own = jnp.sum(sq * scale * scale, axis=1)                    # (B, D h, w)
    count = jnp.sum(part, axis=1)
    pairs2 = count * (count - 1.0)                               # twice the pair count
    ncc = (jnp.sum(total * total, axis=(2, 4)) - own) / jnp.maximum(pairs2, 1.0)
    return jnp.where(count >= 2.0, ncc, 0.0).reshape(b, d, h, w)
