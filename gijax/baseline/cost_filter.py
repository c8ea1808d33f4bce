"""Edge-aware cost aggregation with an image pyramid guided by the reference image.

Each cost slice (one per candidate) is averaged over a support that grows with every pyramid
level, but weighted by colour similarity in the reference (guide) image, so costs do not
bleed across colour edges. The work per level is a constant number of operations per pixel and
each level has a quarter of the pixels of the one below, so the total cost is linear in the
image size (at most 4/3 of one pass over the full-size slices).

Down: a 2x2 block becomes one coarse pixel; every fine pixel q in the block is weighted by
``c_q * exp(-|g_q - g_block|^2 / (2 sigma^2))`` where ``c_q`` is its confidence (0 outside the
valid image) and ``g_block`` the confidence-weighted mean guide colour of the block.
Up: a fine pixel p gathers its 4 bilinear coarse neighbours q with weights
``bilinear(p, q) * c_q * exp(-|g_p - g_q|^2 / (2 sigma^2))`` and blends the result with its own
value: ``((1 - alpha) c_p x_p + alpha c_up x_up) / ((1 - alpha) c_p + alpha c_up)``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from gijax.numerics import safe_denominator

Array = jax.Array

def _range_weight(a: Array, b: Array, sigma: float) -> Array:
    return jnp.exp(-jnp.sum((a - b) ** 2, axis=-1) / (2.0 * sigma * sigma))


def _blocks(x: Array) -> Array:
    """(..., H, W, *rest) with even H, W -> (..., H/2, W/2, 4, *rest) stacking each 2x2 block."""
    return jnp.stack([x[..., 0::2, 0::2], x[..., 0::2, 1::2], x[..., 1::2, 0::2],
                      x[..., 1::2, 1::2]], axis=-1)


def _down(cost: Array, conf: Array, guide: Array, sigma: float):
    """One pyramid step down: cost (D, H, W), conf (H, W), guide (H, W, 3) -> halved sizes."""
    g4 = jnp.stack([guide[0::2, 0::2], guide[0::2, 1::2], guide[1::2, 0::2], guide[1::2, 1::2]],
                   axis=2)  # (h, w, 4, 3)
    c4 = _blocks(conf)  # (h, w, 4)
    g_mean = jnp.sum(g4 * c4[..., None], 2) / safe_denominator(jnp.sum(c4, 2))[..., None]
    w4 = c4 * _range_weight(g4, g_mean[:, :, None], sigma)
    wsum = jnp.sum(w4, -1)
    x4 = _blocks(cost)  # (D, h, w, 4)
    coarse = jnp.sum(x4 * w4, -1) / safe_denominator(wsum)
    # Guides where the block has no confidence fall back to the plain block mean.
    g_plain = jnp.mean(g4, 2)
    g_coarse = jnp.where((jnp.sum(c4, 2) > 0)[..., None], g_mean, g_plain)
    return coarse, 0.25 * wsum, g_coarse


def _neighbours(x: Array, axis: int):
    """For every fine index along ``axis`` (twice the coarse length), the two bilinear coarse
    neighbours of its centre and their weights, built from slices only (no gathers).

    Fine centre ``2i`` sits at coarse ``i - 1/4`` (neighbours ``i - 1``, ``i``; weights 1/4, 3/4)
    and ``2i + 1`` at ``i + 1/4`` (``i``, ``i + 1``; 3/4, 1/4); indices past the edge clamp.
    """
    n = x.shape[axis]
    pad = [(0, 0)] * x.ndim
    pad[axis] = (1, 1)
    rep = jnp.repeat(jnp.pad(x, pad, mode="edge"), 2, axis=axis)
    first = jax.lax.slice_in_dim(rep, 1, 1 + 2 * n, axis=axis)
    second = jax.lax.slice_in_dim(rep, 3, 3 + 2 * n, axis=axis)
    w_first = np.tile(np.array([0.25, 0.75], np.float32), n)
    return (first, second), (w_first, 1.0 - w_first)


def _up(fine_cost: Array, fine_conf: Array, fine_guide: Array, coarse_cost: Array,
        coarse_conf: Array, coarse_guide: Array, sigma: float, alpha: float):
    # Pack confidence, guide and cost slices along the channel axis so that one set of
    # neighbour arrays serves all of them.
    d = coarse_cost.shape[0]
    packed = jnp.concatenate([coarse_conf[..., None], coarse_guide,
                              jnp.moveaxis(coarse_cost, 0, -1)], -1)  # (h, w, 4 + D)
    rows, wrows = _neighbours(packed, 0)
    num = jnp.zeros(fine_conf.shape + (d,), fine_cost.dtype)
    den = jnp.zeros_like(fine_conf)
    for r_arr, wr in zip(rows, wrows):
        cols, wcols = _neighbours(r_arr, 1)
        for nb, wc in zip(cols, wcols):
            wgt = (wr[:, None] * wc[None, :]) * nb[..., 0] * _range_weight(
                fine_guide, nb[..., 1:4], sigma)
            num = num + wgt[..., None] * nb[..., 4:]
            den = den + wgt
    up = jnp.moveaxis(num / safe_denominator(den)[..., None], -1, 0)
    a_f = (1.0 - alpha) * fine_conf
    a_u = alpha * den
    total = a_f + a_u
    blended = (a_f * fine_cost + a_u * up) / safe_denominator(total)
    return blended, total


# One compiled program per setting for eager callers (the pyramid is many small operations).
@functools.partial(jax.jit, static_argnames=("levels", "sigma", "alpha"))
def edge_aware_filter(cost: Array, confidence: Array, guide: Array, levels: int = 4,
                      sigma: float = 0.1, alpha: float = 0.5) -> Array:
    """Filter every cost slice with the guided pyramid.

    Args:
      cost: (D, H, W) matching cost per candidate.
      confidence: (H, W) in [0, 1]; 0 marks pixels whose cost must not spread (invalid).
      guide: (H, W, 3) reference colours in [0, 1].
      levels: number of pyramid levels above full size (0 = no filtering).
      sigma: colour scale of the edge weights (Euclidean RGB distance).
      alpha: share of the coarser level in every up-blend (0 = no smoothing, 1 = coarse only).

    Returns the filtered cost (D, H, W). Pixels with zero confidence and no confident
    neighbourhood keep their input cost. Traceable (jit, vmap, grad in the cost, confidence and
    guide); ``levels``, ``sigma`` and ``alpha`` are static.
    """
    if levels < 0:
        raise ValueError(f"filter levels must be >= 0; found {levels}")
    if levels == 0:
        return cost
    d, h, w = cost.shape
    m = 2 ** levels
    ph, pw = (-h) % m, (-w) % m
    # Pad to a multiple of 2**levels; padding has zero confidence so it never contributes.
    x = jnp.pad(cost, ((0, 0), (0, ph), (0, pw)), mode="edge")
    c = jnp.pad(confidence.astype(cost.dtype), ((0, ph), (0, pw)))
    g = jnp.pad(guide.astype(cost.dtype), ((0, ph), (0, pw), (0, 0)), mode="edge")
    pyramid = [(x, c, g)]
    for _ in range(levels):
        pyramid.append(_down(*pyramid[-1], sigma))
    x_up, c_up, g_up = pyramid[-1]
    for x_f, c_f, g_f in reversed(pyramid[:-1]):
        x_up, c_up = _up(x_f, c_f, g_f, x_up, c_up, g_up, sigma, alpha)
        g_up = g_f
    out = x_up[:, :h, :w]
    return jnp.where(c_up[None, :h, :w] > 0, out, cost)
