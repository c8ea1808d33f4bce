"""Cost-volume builders: fuse swept per-camera features into one volume per candidate and cell.

Input: ``features`` (B, Ncam, D, h, w, C), each camera's feature map sampled at the projection
of every (candidate, cell) point, and ``valid`` (B, Ncam, D, h, w) (bool or float, > 0 = the
camera sees that point: inside its hemisphere, sampled image mask set). Output
(B, D, h, w, out_channels), each builder ending with a 3x3x3 conv + BN + LeakyReLU that lowers
as ``conv3d`` (see :class:`gijax.nn.layers.Conv3D`).

* :class:`ConcatCostVolume`: stacks the cameras' channels (camera-major: camera 0's C channels
  first), Ncam x C channels; the camera count is fixed at construction and, as in the release,
  masks and grid validity are ignored (features are read wherever the grid points).
* :class:`VarianceCostVolume`: per channel, the variance over the valid cameras,
  ``sum_v (f - mean)^2 / count`` (not the standard deviation), 0 where fewer than 2 cameras are
  valid. Independent of the camera order and count, so one set of weights runs any rig.

Both take ``extra`` channels (B, D, h, w, E) concatenated after the fused features, before the
conv, when built with ``extra_channels = E`` (the matching cost, :mod:`gijax.sweep.matching`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx

from gijax.nn.layers import ConvBN

Array = jax.Array


def _check(features: Array, valid: Array, who: str) -> None:
    if features.ndim != 6:
        raise ValueError(f"{who}: features must be (B, Ncam, D, h, w, C), got {features.shape}")
    if valid.shape != features.shape[:5]:
        raise ValueError(
            f"{who}: valid must be (B, Ncam, D, h, w) = {features.shape[:5]}, got {valid.shape}"
        )


def _with_extra(fused: Array, extra: Array | None, channels: int, who: str) -> Array:
    """The fused features (B, D, h, w, F) with the ``channels`` extra channels appended."""
    if channels == 0:
        if extra is not None:
            raise ValueError(f"{who} was built without extra channels; found extra {extra.shape}")
        return fused
    want = (*fused.shape[:4], channels)
    if extra is None or tuple(extra.shape) != want:
        found = None if extra is None else tuple(extra.shape)
        raise ValueError(f"{who} was built for {channels} extra channels of shape {want}; "
                         f"found {found}")
    return jnp.concatenate([fused, extra.astype(fused.dtype)], axis=-1)


def masked_variance(features: Array, valid: Array) -> Array:
    """(B, Ncam, D, h, w, C), (B, Ncam, D, h, w) -> (B, D, h, w, C) variance over valid cameras.

    Divisions are by max(count, 1) and cells with fewer than 2 valid cameras are replaced by 0
    with a select, so values and gradients are finite everywhere. ``valid`` enters only through
    ``valid > 0``, so nothing flows back to it.
    """
    v = (valid > 0).astype(features.dtype)                 # (B, Ncam, D, h, w)
    return _variance(features, v)


def _variance_and_residuals(features: Array, v: Array) -> tuple[Array, Array, Array]:
    # The camera sums as contractions over the camera axis. On XLA's CPU backend this is the
    # fastest form inside the whole forward (G16V-released at paper size: 1.62 s, against
    # 1.83 s with jnp.sum and 6-7 s with the sums written out per camera, which XLA fuses
    # badly with the sweep although that form is the fastest alone).
    # Explicit indices: TensorRT's Einsum takes no ellipsis.
    count = jnp.einsum("bndhw->bdhw", v)[..., None]
    safe = jnp.maximum(count, 1.0)
    mean = jnp.einsum("bndhwc,bndhw->bdhwc", features, v) / safe
    dev = features - mean[:, None]
    var = jnp.einsum("bndhwc,bndhw->bdhwc", dev * dev, v) / safe
    return jnp.where(count >= 2.0, var, 0.0), dev, count


@jax.custom_jvp
def _variance(features: Array, v: Array) -> Array:
    return _variance_and_residuals(features, v)[0]


@_variance.defjvp
def _variance_jvp(primals, tangents):
    # d var = sum_n 2 v_n (f_n - mean) df_n / count: the mean's own derivative drops out,
    # since sum_k v_k (f_k - mean) = 0; the mask is a step function of ``valid``, so its
    # tangent adds nothing. Written out, the gradient (this rule transposed) is one
    # elementwise pass over the swept features; autodiff's transpose of the contractions
    # broadcast the cotangent over the cameras and copied it (60 ms of a 0.9 s CPU training
    # step). A JVP rule, not a VJP one, so forward-mode derivatives still work.
    features, v = primals
    d_features, _ = tangents
    var, dev, count = _variance_and_residuals(features, v)
    weight = dev * (v[..., None] * (2.0 / jnp.maximum(count, 1.0))[:, None])
    d_var = jnp.sum(weight * d_features, axis=1)
    return var, jnp.where(count >= 2.0, d_var, 0.0)


class ConcatCostVolume(nnx.Module):
    """Concatenate the cameras' features -> 3x3x3 conv (Ncam C -> out) + BN + LeakyReLU."""

    def __init__(self, num_cameras: int, channels: int, out_channels: int, rngs: nnx.Rngs,
                 conv3d: str = "auto", extra_channels: int = 0):
        self.num_cameras = num_cameras
        self.channels = channels
        self.extra_channels = extra_channels
        self.fuse = ConvBN(num_cameras * channels + extra_channels, out_channels, 3, 3, rngs,
                           conv3d=conv3d)

    def __call__(self, features: Array, valid: Array, extra: Array | None = None) -> Array:
        _check(features, valid, "ConcatCostVolume")
        b, n, d, h, w, c = features.shape
        if n != self.num_cameras or c != self.channels:
            raise ValueError(
                f"ConcatCostVolume built for {self.num_cameras} cameras x {self.channels} "
                f"channels, got {n} cameras x {c} channels (a concat model's camera count is "
                "fixed; use a variance model for other rigs)"
            )
        stacked = jnp.moveaxis(features, 1, 4).reshape(b, d, h, w, n * c)
        return self.fuse(_with_extra(stacked, extra, self.extra_channels, "ConcatCostVolume"))


class VarianceCostVolume(nnx.Module):
    """Masked variance over the valid cameras -> 3x3x3 conv (C -> out) + BN + LeakyReLU."""

    def __init__(self, channels: int, out_channels: int, rngs: nnx.Rngs, conv3d: str = "auto",
                 extra_channels: int = 0):
        self.channels = channels
        self.extra_channels = extra_channels
        self.fuse = ConvBN(channels + extra_channels, out_channels, 3, 3, rngs, conv3d=conv3d)

    def __call__(self, features: Array, valid: Array, extra: Array | None = None) -> Array:
        _check(features, valid, "VarianceCostVolume")
        if features.shape[-1] != self.channels:
            raise ValueError(
                f"VarianceCostVolume built for {self.channels} channels, "
                f"got {features.shape[-1]}"
            )
        fused = masked_variance(features, valid)
        return self.fuse(_with_extra(fused, extra, self.extra_channels, "VarianceCostVolume"))
