"""Per-candidate matching costs between the reference view and the partner view warped to it.

Two costs, both (D, H, W) in [0, ``clamp``] and equal to ``clamp`` where the partner does not
see the candidate point:

* ``ad`` (the original RTSS cost): ``min(sum_RGB |ref - warped|, clamp)`` on single pixels.
  It assumes equal gain, white balance and vignetting in every camera and a sensor noise well
  below the texture's contrast.
* ``zncc`` (a departure from RTSS): ``min(0.5 * (1 - ncc), clamp)`` with ``ncc`` the zero-mean
  normalised cross-correlation of the ``window x window`` patches around the pixel, the three
  colour channels pooled (each channel centred on its own patch mean, so a per-channel offset
  or gain, e.g. white balance or vignetting, which is constant over a patch, cancels). Pooling
  ``3 * window**2`` samples averages the sensor noise that a 1x1 cost sees in full. With
  ``clamp = 0.5`` every uncorrelated or anti-correlated patch costs the same.

Window sums are separable box sums (``2 * window`` additions per pixel and slice); samples the
partner does not see (or outside the reference view) have zero weight in every sum.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

Array = jax.Array
COST_KINDS = ("ad", "zncc")
# Product of the two pooled patch variances below which a patch counts as textureless (its
# correlation is then 0, i.e. a neutral cost): only exactly flat patches, e.g. saturated ones.
_FLAT = 1e-12


def ad_cost(ref: Array, warped: Array, ok: Array, clamp: float) -> Array:
    """Absolute RGB difference of single pixels: ref (H, W, 3), warped (D, H, W, 3), ok (D, H, W)."""
    cost = jnp.sum(jnp.abs(warped - ref[None]), -1)
    return jnp.where(ok, jnp.minimum(cost, clamp), clamp)


def box_sum(x: Array, window: int) -> Array:
    """Sum over the ``window x window`` neighbourhood of every pixel of x (..., H, W, C).

    Zero padding outside the image (weights must be carried along as a channel to normalise).
    """
    pad = window // 2
    lead = x.ndim - 3

    def along(arr, axis):
        dims = [1] * arr.ndim
        dims[axis] = window
        padding = [(0, 0)] * arr.ndim
        padding[axis] = (pad, pad)
        return jax.lax.reduce_window(arr, 0.0, jax.lax.add, tuple(dims), (1,) * arr.ndim,
                                     padding)

    return along(along(x, lead), lead + 1)


def zncc_cost(ref: Array, warped: Array, ok: Array, clamp: float, window: int = 7) -> Array:
    """Zero-mean normalised cross-correlation cost ``min(0.5 (1 - ncc), clamp)`` (D, H, W).

    Args:
      ref: (H, W, 3) reference view in [0, 1].
      warped: (D, H, W, 3) partner view sampled at every candidate's point.
      ok: (D, H, W) the partner sees the candidate point and the reference pixel is valid.
      clamp: upper bound and cost of unseen candidates.
      window: odd patch width in pixels.

    A pixel whose patch has fewer than half its samples seen costs ``clamp``.
    """
    if window < 1 or window % 2 == 0:
        raise ValueError(f"the matching window must be an odd number of pixels; found {window}")
    # One candidate slice at a time: the 16 window sums of a slice are the only temporaries,
    # so memory stays D x H x W like the 1x1 cost.
    return jax.lax.map(lambda args: _zncc_slice(ref, args[0], args[1], clamp, window),
                       (warped, ok))


def _zncc_slice(ref: Array, warped: Array, ok: Array, clamp: float, window: int) -> Array:
    """:func:`zncc_cost` of one candidate: warped (H, W, 3), ok (H, W) -> (H, W)."""
    w = ok[..., None].astype(warped.dtype)
    r = ref * w
    x = warped * w
    # Channel layout: [w, r (3), x (3), r*r (3), x*x (3), r*x (3)] summed in one pass.
    sums = box_sum(jnp.concatenate([w, r, x, r * r, x * x, r * x], -1), window)
    n = sums[..., 0:1]
    inv_n = 1.0 / jnp.maximum(n, 1.0)
    mr, mx = sums[..., 1:4] * inv_n, sums[..., 4:7] * inv_n
    var_r = jnp.sum(jnp.maximum(sums[..., 7:10] * inv_n - mr * mr, 0.0), -1)
    var_x = jnp.sum(jnp.maximum(sums[..., 10:13] * inv_n - mx * mx, 0.0), -1)
    cov = jnp.sum(sums[..., 13:16] * inv_n - mr * mx, -1)
    prod = var_r * var_x
    ncc = jnp.where(prod > _FLAT, cov / jnp.sqrt(jnp.where(prod > _FLAT, prod, 1.0)), 0.0)
    cost = jnp.minimum(0.5 * (1.0 - ncc), clamp)
    enough = n[..., 0] >= 0.5 * window * window
    return jnp.where(ok & enough, cost, clamp)


def matching_cost(kind: str, ref: Array, warped: Array, ok: Array, clamp: float,
                  window: int) -> Array:
    """The cost (D, H, W) named ``kind`` ('ad' ignores ``window``: 1x1 by definition)."""
    if kind == "ad":
        return ad_cost(ref, warped, ok, clamp)
    if kind == "zncc":
        return zncc_cost(ref, warped, ok, clamp, window)
    raise ValueError(f"unknown matching cost {kind!r}; expected one of {COST_KINDS}")
