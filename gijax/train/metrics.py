"""Evaluation metrics on inverse distance (1/m), as in the paper's tables.

Shapes: predicted inverse distance ``inv_pred`` (B, H, W) in 1/m, label ``distance`` (B, H, W)
in metres (sky / no hit stored as 1e6 m), ``valid`` (B, H, W), ``candidates`` (D,) ascending
metres. The label is converted to inverse distance and clamped to the candidate range
[1/d_max, 1/d_min] (0.01..2 for the paper's 0.5..100 m) before every metric.

* MAE and RMSE: over usable pixels (valid, finite positive label) of ``|inv_pred - inv_gt|``.
* SSIM: Wang et al. (2004) with an 11 x 11 Gaussian window (sigma 1.5, normalised to sum 1),
  zero padding at the borders ('same' size), constants ``C1 = (0.01 L)^2``, ``C2 = (0.03 L)^2``
  with data range ``L = 1`` by default (the constants of the common PyTorch SSIM used by
  the original release), averaged over the whole image. Unusable label pixels take the predicted
  value, so they neither help nor hurt the structure term.
* Bad-pixel rates ``bad_0.1`` and ``bad_0.4``: fraction of usable pixels whose absolute
  inverse-distance error ``|inv_pred - inv_gt|`` exceeds 0.1 and 0.4 1/m. The thresholds of
  Meuleman et al. (2021) apply to absolute inverse-depth error; here that error is taken in 1/m
  on the clamped labels (0.1 and 0.4 1/m are 5 % and 20 % of the 0.01..2 range).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from gijax.train.losses import clamped_inverse, label_mask

Array = jax.Array

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
BAD_THRESHOLDS = (0.1, 0.4)


def gaussian_window_1d(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """(size,) Gaussian weights centred on the middle tap, normalised to sum 1."""
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2.0
    g = np.exp(-(x * x) / (2.0 * sigma * sigma))
    return (g / g.sum()).astype(np.float32)


def _blur(x: Array, taps: np.ndarray) -> Array:
    """Separable 'same' Gaussian filter with zero padding on (B, H, W)."""
    k = jnp.asarray(taps)
    n = k.shape[0]
    y = x[:, None]                                             # (B, 1, H, W)
    kh = k.reshape(1, 1, n, 1)
    kw = k.reshape(1, 1, 1, n)
    pad = n // 2
    y = jax.lax.conv_general_dilated(y, kh, (1, 1), ((pad, pad), (0, 0)))
    y = jax.lax.conv_general_dilated(y, kw, (1, 1), ((0, 0), (pad, pad)))
    return y[:, 0]


def ssim_map(x: Array, y: Array, data_range: float = 1.0, window: int = SSIM_WINDOW,
             sigma: float = SSIM_SIGMA) -> Array:
    """(B, H, W) SSIM map between two image batches (B, H, W) (see the module docstring)."""
    taps = gaussian_window_1d(window, sigma)
    x = x.astype(jnp.float32)
    y = y.astype(jnp.float32)
    c1 = (0.01 * data_range) ** 2
    c2 = (0.03 * data_range) ** 2
    mx, my = _blur(x, taps), _blur(y, taps)
    sxx = _blur(x * x, taps) - mx * mx
    syy = _blur(y * y, taps) - my * my
    sxy = _blur(x * y, taps) - mx * my
    return ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))


def inverse_errors(inv_pred: Array, distance: Array, valid: Array, candidates: Array):
    """Per-pixel ``inv_pred - inv_gt`` (B, H, W), usable-pixel mask (B, H, W), clamped target."""
    target = clamped_inverse(distance, candidates)
    m = label_mask(distance, valid)
    return inv_pred.astype(jnp.float32) - target, m, target


@functools.partial(jax.jit, static_argnames=("data_range",))
def batch_sums(inv_pred: Array, distance: Array, valid: Array, candidates: Array,
               data_range: float = 1.0) -> dict:
    """Per-sample sums for accumulating metrics over many batches (each value has shape (B,)).

    Keys: ``count`` (usable pixels), ``abs`` (sum |e|), ``sq`` (sum e^2), ``bad_0.1`` and
    ``bad_0.4`` (counts), ``ssim`` (mean SSIM of each sample over its whole image).
    """
    err, m, target = inverse_errors(inv_pred, distance, valid, candidates)
    filled = jnp.where(m > 0, target, inv_pred.astype(jnp.float32))
    out = {
        "count": jnp.sum(m, axis=(1, 2)),
        "abs": jnp.sum(jnp.abs(err) * m, axis=(1, 2)),
        "sq": jnp.sum(err * err * m, axis=(1, 2)),
        "ssim": jnp.mean(ssim_map(inv_pred, filled, data_range), axis=(1, 2)),
    }
    for t in BAD_THRESHOLDS:
        out[f"bad_{t}"] = jnp.sum((jnp.abs(err) > t) * m, axis=(1, 2))
    return out


def summarize(sums: dict) -> dict:
    """Dataset metrics from concatenated per-sample sums (numpy or jax arrays of shape (N,)).

    MAE, RMSE and the bad-pixel rates pool all usable pixels of all samples; SSIM is the mean
    of the per-sample SSIMs (each over its whole image).
    """
    count = float(np.sum(sums["count"]))
    denom = max(count, 1.0)
    out = {
        "mae": float(np.sum(sums["abs"])) / denom,
        "rmse": float(np.sqrt(float(np.sum(sums["sq"])) / denom)),
        "ssim": float(np.mean(sums["ssim"])) if len(np.atleast_1d(sums["ssim"])) else float("nan"),
        "pixels": int(count),
        "samples": int(len(np.atleast_1d(sums["count"]))),
    }
    for t in BAD_THRESHOLDS:
        out[f"bad_{t}"] = float(np.sum(sums[f"bad_{t}"])) / denom
    return out


def evaluate_batch(inv_pred: Array, distance: Array, valid: Array, candidates: Array,
                   data_range: float = 1.0) -> dict:
    """Metrics of one batch as Python floats: mae, rmse, ssim, bad_0.1, bad_0.4, pixels, samples."""
    sums = batch_sums(inv_pred, distance, valid, jnp.asarray(candidates, jnp.float32),
                      data_range=data_range)
    return summarize(jax.tree.map(np.asarray, sums))
