"""Evaluation metrics on inverse distance (1/m): the paper's definitions and gijax's own.

Shapes: predicted inverse distance ``inv_pred`` (B, H, W) in 1/m, label ``distance`` (B, H, W)
in metres (sky / no hit stored as 1e6 m), ``valid`` (B, H, W) (usable label and, where a method
leaves holes, an estimate), ``candidates`` (D,) ascending metres. Two sets of definitions,
chosen by ``metric_set``:

``'paper'``: the metrics as the authors' release computed them for the paper's tables. The
release works in units of ``bf/d`` with ``bf = 96`` and divides both maps by ``bf`` before every
metric, so everything is on inverse distance in 1/m, as here. It evaluated one sample per
batch and averaged the per-batch values, so each metric is computed per sample and then
averaged over samples (whatever the batch size here).

* Pixel set for MAE, RMSE and the bad-pixel rates: usable labels whose distance lies inside
  the candidate range, ``candidates[0] <= d <= candidates[-1]`` (0.5 m to 100 m for every paper
  model), both ends included. Sky (1e6 m) and anything nearer than the nearest candidate are
  left out, not clamped.
* MAE and RMSE: per sample, the mean of ``|e|`` and the root of the mean of ``e^2`` over that
  pixel set (``e = inv_pred - 1/d``); the dataset value is the mean over samples. A sample with
  no pixel in the set is skipped (the release would have produced NaN).
* SSIM: ``torchmetrics.functional.structural_similarity_index_measure`` with its defaults as of
  the release (torchmetrics < 1.5): 11 x 11 Gaussian window (sigma 1.5, the outer product of
  two 1-D windows each normalised to sum 1), reflect padding of 5 pixels (the edge pixel is not
  repeated), biased (Gaussian-weighted) variances clamped at 0, ``C1 = (0.01 L)^2``,
  ``C2 = (0.03 L)^2`` with ``L = max(ptp(pred), ptp(target))`` taken from the sample itself,
  and the mean over the map after cropping its 5-pixel border. torchmetrics 1.5 dropped that
  crop; the paper's figures predate it. The target is the label inverse distance clamped to
  the candidate range (sky -> 1/100, nearer than 0.5 m -> 2), over the whole image, unmasked
  (the release's SSIM takes no mask). Where ``valid`` is false the target takes the predicted
  value (the release's labels had no such pixels). Because ``L`` comes from the data, SSIM on
  ``96/d`` and on 1/m are the same number (both constants scale with the square of the
  values); it is computed on 1/m, like the release.
* Bad-pixel rates ``bad_0.1`` / ``bad_0.4``: per sample, the share of the MAE pixel set whose
  ``|e|`` exceeds 0.1 / 0.4 1/m (the release's BadPixelRatioMetric on 1/m), mean over samples.

``'gijax'``: gijax's own definitions (the validation metric of ``gijax train``).

* The label is converted to inverse distance and clamped to the candidate range
  ``[1/d_max, 1/d_min]`` (0.01..2 for 0.5..100 m) before every metric, so sky pixels (error
  against 0.01) and pixels nearer than 0.5 m (error against 2) are scored.
* MAE, RMSE and bad-pixel rates: pooled over all usable pixels (``valid``, finite positive
  label) of all samples.
* SSIM: Wang et al. (2004) with an 11 x 11 Gaussian window (sigma 1.5, normalised to sum 1),
  zero padding at the borders ('same' size), fixed ``C1 = (0.01 L)^2``, ``C2 = (0.03 L)^2`` with
  ``L = 1`` by default, averaged over the whole image including its border; the mean of the
  per-sample values. Unusable label pixels take the predicted value.

Pixels a method leaves without an estimate (RTSS where no camera pair matched; ``pred_valid``
False, or a non-finite prediction) are lost coverage in both sets, never NaN: they are left out
of MAE, RMSE and the bad-pixel rates, the share of scored label pixels that do have an
estimate is reported as ``coverage``, and SSIM, which needs a whole image, sees them at the far
end of the candidate range (``1 / candidates[-1]``, "nothing found nearer"), so a method that
leaves holes where something is near loses SSIM there.

The thresholds of the bad-pixel rates (Meuleman et al. 2021) apply to absolute inverse-depth
error, taken here in 1/m (0.1 and 0.4 1/m are 5 % and 20 % of the 0.01..2 range).

Computation is in float32, or float64 when the inputs are (:func:`gijax.numerics.float_dtype`).
The per-sample functions are traceable (jit, vmap, grad in the prediction); the edges that
return Python numbers (:func:`summarize`, :func:`evaluate_batch`), validate a name
(:func:`check_metric_set`) or build a NumPy constant (:func:`gaussian_window_1d`) are not.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from gijax.numerics import float_dtype, sqrt_or_zero
from gijax.evaluate.labels import clamped_inverse, label_mask

Array = jax.Array

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
BAD_THRESHOLDS = (0.1, 0.4)
METRIC_SETS = ("paper", "gijax")
# Per-sample values each set's batch_sums returns (summarize checks them).
SUM_KEYS = {
    "paper": ("count", "scored", "mae", "rmse", "ssim") + tuple(f"bad_{t}" for t in BAD_THRESHOLDS),
    "gijax": ("count", "scored", "abs", "sq", "ssim") + tuple(f"bad_{t}" for t in BAD_THRESHOLDS),
}


def check_metric_set(metric_set: str) -> str:
    if metric_set not in METRIC_SETS:
        raise ValueError(f"metric_set must be one of {METRIC_SETS}; found {metric_set!r}")
    return metric_set


def gaussian_window_1d(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """(size,) Gaussian weights centred on the middle tap, normalised to sum 1."""
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2.0
    g = np.exp(-(x * x) / (2.0 * sigma * sigma))
    return (g / g.sum()).astype(np.float32)


def _blur(x: Array, taps: np.ndarray, padding: str = "zero") -> Array:
    """Separable Gaussian filter on (B, H, W), output (B, H, W).

    ``padding='zero'``: 'same' convolution with zeros outside. ``'reflect'``: the image is
    mirrored about its edge pixels (numpy / torch 'reflect') before a 'valid' convolution.
    """
    k = jnp.asarray(taps, x.dtype)
    n = k.shape[0]
    pad = n // 2
    if padding == "reflect":
        x = jnp.pad(x, ((0, 0), (pad, pad), (pad, pad)), mode="reflect")
        pad_h = pad_w = ((0, 0), (0, 0))                       # 'valid' on the padded image
    elif padding == "zero":
        pad_h, pad_w = ((pad, pad), (0, 0)), ((0, 0), (pad, pad))
    else:
        raise ValueError(f"padding must be 'zero' or 'reflect'; found {padding!r}")
    y = x[:, None]                                             # (B, 1, H, W)
    y = jax.lax.conv_general_dilated(y, k.reshape(1, 1, n, 1), (1, 1), pad_h)
    y = jax.lax.conv_general_dilated(y, k.reshape(1, 1, 1, n), (1, 1), pad_w)
    return y[:, 0]


def ssim_map(x: Array, y: Array, data_range: float = 1.0, window: int = SSIM_WINDOW,
             sigma: float = SSIM_SIGMA) -> Array:
    """(B, H, W) SSIM map of gijax's definition: zero padding, fixed data range (module doc)."""
    taps = gaussian_window_1d(window, sigma)
    dt = float_dtype(x, y)
    x = x.astype(dt)
    y = y.astype(dt)
    c1 = (0.01 * data_range) ** 2
    c2 = (0.03 * data_range) ** 2
    mx, my = _blur(x, taps), _blur(y, taps)
    sxx = _blur(x * x, taps) - mx * mx
    syy = _blur(y * y, taps) - my * my
    sxy = _blur(x * y, taps) - mx * my
    return ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))


def paper_ssim(x: Array, y: Array) -> Array:
    """(B,) SSIM of each image pair as torchmetrics (< 1.5) computes it with its defaults on a
    batch of one: data range from the pair, reflect padding, 5-pixel border cropped.

    ``x`` the prediction, ``y`` the target, both (B, H, W) with H, W > 10. A pair of constant
    images has data range 0 and gives NaN, as in torchmetrics.
    """
    if x.shape != y.shape or x.ndim != 3:
        raise ValueError(f"paper_ssim takes two (B, H, W) batches of one shape; found "
                         f"{x.shape} and {y.shape}")
    pad = SSIM_WINDOW // 2
    if min(x.shape[1:]) <= 2 * pad:
        raise ValueError(f"SSIM needs images larger than {2 * pad} x {2 * pad} (its window "
                         f"border is cropped); found {x.shape[1:]}")
    taps = gaussian_window_1d(SSIM_WINDOW, SSIM_SIGMA)
    dt = float_dtype(x, y)
    x = x.astype(dt)
    y = y.astype(dt)
    ptp = lambda a: jnp.max(a, axis=(1, 2)) - jnp.min(a, axis=(1, 2))  # noqa: E731
    data_range = jnp.maximum(ptp(x), ptp(y))[:, None, None]
    c1 = (0.01 * data_range) ** 2
    c2 = (0.03 * data_range) ** 2
    mx, my = _blur(x, taps, "reflect"), _blur(y, taps, "reflect")
    mxx, myy, mxy = mx * mx, my * my, mx * my
    # Rounding can make E[x^2] - E[x]^2 slightly negative; torchmetrics clamps it at 0.
    sxx = jnp.maximum(_blur(x * x, taps, "reflect") - mxx, 0.0)
    syy = jnp.maximum(_blur(y * y, taps, "reflect") - myy, 0.0)
    sxy = _blur(x * y, taps, "reflect") - mxy
    s = ((2 * mxy + c1) * (2 * sxy + c2)) / ((mxx + myy + c1) * (sxx + syy + c2))
    return jnp.mean(s[:, pad:-pad, pad:-pad], axis=(1, 2))


def _fill_unmatched(inv_pred: Array, pred_valid, candidates: Array) -> tuple[Array, Array]:
    """The prediction with pixels that have no estimate set to the far end of the candidate
    range, and the (B, H, W) bool mask of pixels that have one (``pred_valid`` and finite)."""
    matched = jnp.isfinite(inv_pred)
    if pred_valid is not None:
        matched = matched & jnp.asarray(pred_valid, bool)
    far = 1.0 / jnp.asarray(candidates[-1], inv_pred.dtype)
    return jnp.where(matched, inv_pred, far), matched


def inverse_errors(inv_pred: Array, distance: Array, valid: Array, candidates: Array):
    """Per-pixel ``inv_pred - inv_gt`` (B, H, W), usable-pixel mask (B, H, W), clamped target."""
    target = clamped_inverse(distance, candidates)
    m = label_mask(distance, valid)
    return inv_pred.astype(float_dtype(inv_pred, target)) - target, m, target


def paper_label_mask(distance: Array, valid: Array, candidates: Array) -> Array:
    """(B, H, W) float32: 1 where the label is usable and inside the candidate range
    ``candidates[0] <= d <= candidates[-1]`` (the paper's pixel set for MAE and RMSE)."""
    dt = float_dtype(distance, candidates)
    cand = jnp.asarray(candidates, dt)
    d = distance.astype(dt)
    inside = (d >= cand[0]) & (d <= cand[-1])
    return label_mask(distance, valid) * inside.astype(jnp.float32)


def paper_sample_metrics(inv_pred: Array, distance: Array, valid: Array,
                         candidates: Array, pred_valid: Array | None = None) -> dict:
    """Per-sample values of the paper's definitions (each (B,); see the module docstring).

    ``pred_valid`` (B, H, W) marks the pixels the method estimated (None: every finite one).
    Keys: ``scored`` (label pixels in the MAE set), ``count`` (those with an estimate),
    ``mae``, ``rmse``, ``bad_0.1``, ``bad_0.4`` (0 where ``count`` is 0) and ``ssim``.
    """
    target = clamped_inverse(distance, candidates)
    inv_pred, matched = _fill_unmatched(inv_pred.astype(float_dtype(inv_pred, target)),
                                        pred_valid, candidates)
    scored = paper_label_mask(distance, valid, candidates)
    m = scored * matched.astype(scored.dtype)
    err = inv_pred - target              # inside the range the clamp leaves the label alone
    count = jnp.sum(m, axis=(1, 2))
    denom = jnp.maximum(count, 1.0)
    filled = jnp.where(label_mask(distance, valid) > 0, target, inv_pred)
    out = {
        "count": count,
        "scored": jnp.sum(scored, axis=(1, 2)),
        "mae": jnp.sum(jnp.abs(err) * m, axis=(1, 2)) / denom,
        # sqrt(0) (no pixel, or a perfect prediction) has an infinite derivative.
        "rmse": sqrt_or_zero(jnp.sum(err * err * m, axis=(1, 2)) / denom),
        "ssim": paper_ssim(inv_pred, filled),
    }
    for t in BAD_THRESHOLDS:
        out[f"bad_{t}"] = jnp.sum((jnp.abs(err) > t) * m, axis=(1, 2)) / denom
    return out


def gijax_batch_sums(inv_pred: Array, distance: Array, valid: Array, candidates: Array,
                     data_range: float = 1.0, pred_valid: Array | None = None) -> dict:
    """Per-sample sums of gijax's definitions (each (B,)).

    ``pred_valid`` (B, H, W) marks the pixels the method estimated (None: every finite one).
    Keys: ``scored`` (usable label pixels), ``count`` (those with an estimate), ``abs`` (sum
    |e|), ``sq`` (sum e^2), ``bad_0.1`` and ``bad_0.4`` (counts), ``ssim`` (mean SSIM of each
    sample over its whole image).
    """
    inv_pred, matched = _fill_unmatched(inv_pred, pred_valid, candidates)
    err, scored, target = inverse_errors(inv_pred, distance, valid, candidates)
    m = scored * matched.astype(scored.dtype)
    filled = jnp.where(scored > 0, target, inv_pred.astype(err.dtype))
    out = {
        "count": jnp.sum(m, axis=(1, 2)),
        "scored": jnp.sum(scored, axis=(1, 2)),
        "abs": jnp.sum(jnp.abs(err) * m, axis=(1, 2)),
        "sq": jnp.sum(err * err * m, axis=(1, 2)),
        "ssim": jnp.mean(ssim_map(inv_pred, filled, data_range), axis=(1, 2)),
    }
    for t in BAD_THRESHOLDS:
        out[f"bad_{t}"] = jnp.sum((jnp.abs(err) > t) * m, axis=(1, 2))
    return out


@functools.partial(jax.jit, static_argnames=("data_range", "metric_set"))
def batch_sums(inv_pred: Array, distance: Array, valid: Array, candidates: Array,
               data_range: float = 1.0, metric_set: str = "gijax",
               pred_valid: Array | None = None) -> dict:
    """Per-sample values for accumulating metrics over many batches (each of shape (B,)).

    ``metric_set`` 'paper' -> :func:`paper_sample_metrics`, 'gijax' ->
    :func:`gijax_batch_sums` (``data_range`` applies to gijax's SSIM only). ``pred_valid``
    (B, H, W) marks the pixels the method estimated (None: every finite one; the others are
    lost coverage, see the module docstring). Concatenate the values of all batches and pass
    them to :func:`summarize` with the same ``metric_set``.
    """
    check_metric_set(metric_set)
    if metric_set == "paper":
        return paper_sample_metrics(inv_pred, distance, valid, candidates, pred_valid)
    return gijax_batch_sums(inv_pred, distance, valid, candidates, data_range, pred_valid)


def summarize(sums: dict, metric_set: str = "gijax") -> dict:
    """Dataset metrics from concatenated per-sample values (arrays of shape (N,)).

    'paper': MAE, RMSE and bad-pixel rates are means of the per-sample values over the samples
    with at least one pixel in range (NaN if none has), SSIM the mean over all samples.
    'gijax': MAE, RMSE and bad-pixel rates pool all usable pixels of all samples; SSIM is the
    mean of the per-sample SSIMs. Both return mae, rmse, ssim, bad_0.1, bad_0.4, pixels
    (scored pixels with an estimate), coverage (their share of all scored pixels) and samples
    as Python numbers.
    """
    check_metric_set(metric_set)
    missing = [k for k in SUM_KEYS[metric_set] if k not in sums]
    if missing:
        raise ValueError(f"summarize(metric_set={metric_set!r}) needs the per-sample values "
                         f"{SUM_KEYS[metric_set]}; missing {missing} (were they computed with "
                         f"another metric_set?)")
    count = np.asarray(sums["count"], np.float64).reshape(-1)
    scored = float(np.sum(np.asarray(sums["scored"], np.float64)))
    ssim = np.asarray(sums["ssim"], np.float64).reshape(-1)
    out = {"ssim": float(np.mean(ssim)) if ssim.size else float("nan"),
           "pixels": int(np.sum(count)), "samples": int(count.size),
           # Share of the scored label pixels the method gave an estimate (1 with no label).
           "coverage": float(np.sum(count)) / scored if scored > 0 else 1.0}
    if metric_set == "paper":
        has = count > 0
        mean = (lambda k: float(np.mean(np.asarray(sums[k], np.float64).reshape(-1)[has]))
                if np.any(has) else float("nan"))
        out.update(mae=mean("mae"), rmse=mean("rmse"))
        for t in BAD_THRESHOLDS:
            out[f"bad_{t}"] = mean(f"bad_{t}")
        return out
    denom = max(float(np.sum(count)), 1.0)
    out.update(mae=float(np.sum(sums["abs"])) / denom,
               rmse=float(np.sqrt(float(np.sum(sums["sq"])) / denom)))
    for t in BAD_THRESHOLDS:
        out[f"bad_{t}"] = float(np.sum(sums[f"bad_{t}"])) / denom
    return out


def evaluate_batch(inv_pred: Array, distance: Array, valid: Array, candidates: Array,
                   data_range: float = 1.0, metric_set: str = "gijax",
                   pred_valid: Array | None = None) -> dict:
    """Metrics of one batch as Python numbers: mae, rmse, ssim, bad_0.1, bad_0.4, pixels,
    coverage, samples (``metric_set`` 'paper' or 'gijax', see the module docstring)."""
    sums = batch_sums(inv_pred, distance, valid, jnp.asarray(candidates, jnp.float32),
                      data_range=data_range, metric_set=metric_set, pred_valid=pred_valid)
    return summarize(jax.tree.map(np.asarray, sums), metric_set)
