"""Spherical 3x3 convolution on an equirectangular feature map (fixed tangent-plane offsets).

Two tap layouts (``taps``), chosen by ``ModelConfig.spherical_taps``:

* ``'release'`` (the released G16VV, and the default): the offsets the authors' code computes
  and feeds to torchvision's ``deform_conv2d`` (:func:`release_offsets`). ``deform_conv2d`` adds
  them to its own 3x3 kernel grid, but they already hold each tap's full displacement from the
  pixel, so the taps land about twice the tangent-plane spacing apart, shifted by +0.5 px, and
  longitude is wrapped with ``% (W - 1)``. Sampling is bilinear with zero padding, as in
  ``deform_conv2d``. Released G16VV weights were trained with these taps and need them.
* ``'tangent'``: the kernel the paper describes, derived below.

An equirectangular map stretches the sphere in longitude by 1 / cos(lat): near the pole a plain
3x3 kernel covers a sliver of solid angle. The spherical conv instead samples its 9 taps where a
3x3 grid laid on the plane tangent to the sphere at the output pixel lands, so the kernel covers
the same solid angle everywhere (a deformable conv whose offsets are fixed and precomputed).

Derivation of the taps
----------------------
Feature-map pixel (col c, row r) of an H x W map over latitudes [lat0, lat1] has its centre at
``lon = -pi + (c + 0.5) dlon`` and ``lat = lat0 + (r + 0.5) dlat`` with ``dlon = 2 pi / W``,
``dlat = (lat1 - lat0) / H``. Write the centre as the unit vector ``P = (cos lat cos lon,
cos lat sin lon, sin lat)`` with local east ``e = (-sin lon, cos lon, 0)`` and north
(increasing latitude, i.e. increasing row) ``n = (-sin lat cos lon, -sin lat sin lon, cos lat)``.
The plane tangent at P (at unit distance from the centre) holds the 3x3 grid

    q(i, j) = P + j tan(dlon) e + i tan(dlat) n,   i, j in {-1, 0, 1}

(i: row step, j: column step); its scale makes the four edge taps at the equator land exactly
one pixel away. The tap direction is q / |q| (the inverse gnomonic projection), so

    lat_ij = asin(q_z / |q|),   lon_ij = atan2(q . e', q . P')

where the longitude is measured about the polar axis. Taking lon = 0 without loss of generality
(the map is invariant to rotation about the pole, so offsets depend on the row only):
``q = (cos lat - i tan(dlat) sin lat, j tan(dlon), sin lat + i tan(dlat) cos lat)``, and the
offsets in pixels are ``d_row = (lat_ij - lat) / dlat``, ``d_col = lon_ij / dlon``.

* At the equator (lat = 0), with t = tan(d) for square pixels d = dlat = dlon: the edge taps
  land exactly one pixel away (atan(t) = d); a corner tap is q = (1, t, t), i.e. one column
  away exactly and asin(t / sqrt(1 + 2 t^2)) / d = 1 - O(d^2) rows away: the plain 3x3 grid.
* For the side taps (i = 0): ``lon = atan(tan(dlon) / cos(lat))`` and
  ``lat' = asin(sin(lat) cos(dlon))``: the kernel widens in longitude by about 1 / cos(lat).
* Near the pole a tap with i = -1 crosses the pole: its latitude stays above -90 deg and its
  longitude jumps by about 180 deg, which is where the neighbouring pixel really lies.

Sampling: bilinear, longitude wrapping around (column indices modulo W); a row coordinate above
the first row centre (only within half a pixel of the pole) is clamped to row 0, and rows past
the last one (beyond the hemisphere's horizon, where the surrogate image is empty) read zeros,
as the zero padding of a plain conv would. The 9 sampled vectors are stacked tap-major
(tap k = 3 (i + 1) + (j + 1), then channel) and mixed by one (9 C) -> C_out matrix, the layout
of a 3x3 conv kernel (3, 3, C, C_out) reshaped, so parameter counts equal the plain conv's.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from gijax.nn.layers import batch_norm, kernel_init, leaky_relu

Array = jax.Array


def tangent_offsets(height: int, width: int, lat_min: float = -math.pi / 2,
                    lat_max: float = 0.0) -> np.ndarray:
    """(H, 9, 2) float64 tap offsets (d_row, d_col) in pixels for every row of an H x W map.

    Tap k = 3 (i + 1) + (j + 1) for row step i and column step j in {-1, 0, 1}. Column offsets
    are wrapped into [-W/2, W/2).
    """
    dlat = (lat_max - lat_min) / height
    dlon = 2 * math.pi / width
    lat = lat_min + (np.arange(height) + 0.5) * dlat  # (H,)
    i, j = np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], indexing="ij")
    i = i.reshape(1, 9)
    j = j.reshape(1, 9)
    s = np.sin(lat)[:, None]
    c = np.cos(lat)[:, None]
    ty, tx = math.tan(dlat), math.tan(dlon)
    # Tangent-plane point q = P + j tx e + i ty n for the pixel at longitude 0.
    qx = c - i * ty * s
    qy = j * tx * np.ones_like(c)
    qz = s + i * ty * c
    norm = np.sqrt(qx**2 + qy**2 + qz**2)
    tap_lat = np.arcsin(np.clip(qz / norm, -1.0, 1.0))
    tap_lon = np.arctan2(qy, qx)
    d_row = (tap_lat - lat[:, None]) / dlat
    d_col = tap_lon / dlon
    d_col = (d_col + width / 2) % width - width / 2
    return np.stack([d_row, d_col], axis=-1)


def sampling_tables(offsets: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Gather indices and weights for bilinear sampling at per-row tap offsets.

    ``offsets`` (H, K, 2) = (d_row, d_col) pixels. Returns ``index`` (4, H, W, K) int32 flat
    indices ``row * W + col`` into an (H, W) map and ``weight`` (4, H, 1, K) float32 for the four
    neighbours (row0/col0, row0/col1, row1/col0, row1/col1). Neighbours in rows beyond the last
    one get weight 0; rows above row 0 are clamped to row 0; columns wrap.
    """
    height, n_taps = offsets.shape[0], offsets.shape[1]
    rows = np.arange(height, dtype=np.float64)[:, None] + offsets[..., 0]  # (H, K)
    rows = np.maximum(rows, 0.0)
    r0 = np.floor(rows)
    fr = rows - r0
    r0 = r0.astype(np.int64)
    r1 = r0 + 1
    dc = offsets[..., 1]
    c_shift = np.floor(dc)
    fc = dc - c_shift
    c_shift = c_shift.astype(np.int64)
    cols = np.arange(width, dtype=np.int64)
    index = np.zeros((4, height, width, n_taps), np.int32)
    weight = np.zeros((4, height, 1, n_taps), np.float32)
    for n, (rr, dcol, wr, wc) in enumerate(
        [(r0, 0, 1 - fr, 1 - fc), (r0, 1, 1 - fr, fc), (r1, 0, fr, 1 - fc), (r1, 1, fr, fc)]
    ):
        inside = rr <= height - 1
        rr_c = np.minimum(rr, height - 1)
        col = (cols[None, :, None] + c_shift[:, None, :] + dcol) % width  # (H, W, K)
        index[n] = (rr_c[:, None, :] * width + col).astype(np.int32)
        weight[n, :, 0, :] = np.where(inside, wr * wc, 0.0)
    return index, weight


def _four_neighbours(flat: Array, index: Array, weight: Array) -> Array:
    """Sum over the four bilinear neighbours: ``flat`` (B, H W, C), ``index`` (4, *S) flat
    indices, ``weight`` (4, *S') broadcastable to S -> (B, *S, C)."""
    b, _, c = flat.shape
    out = None
    for n in range(4):
        got = jnp.take(flat, index[n].reshape(-1), axis=1).reshape(b, *index.shape[1:], c)
        term = got * weight[n][None, ..., None].astype(flat.dtype)
        out = term if out is None else out + term
    return out


def gather_taps(x: Array, index: Array, weight: Array) -> Array:
    """Bilinear taps of ``x`` (B, H, W, C) from :func:`sampling_tables` -> (B, H, W, K, C)."""
    b, h, w, c = x.shape
    return _four_neighbours(x.reshape(b, h * w, c), index, weight)


def mix_taps_one_by_one(x: Array, index: Array, weight: Array, kernel: Array) -> Array:
    """``gather_taps`` then the (K C) -> C_out mix, one tap at a time: (B, H, W, C) ->
    (B, H, W, C_out) with ``kernel`` (K C, C_out) tap-major.

    The same sums in another order: no (B, H, W, K, C) stack is ever held, only one tap's
    (B, H, W, C) samples. At the paper's size the stack of the four neighbours is about
    0.1 GB per neighbour, which dominates onnxruntime's working set; in JAX this form is also
    faster forward (CPU), but its backward is slower, so training keeps the stacked form.
    """
    b, h, w, c = x.shape
    k = index.shape[-1]
    flat = x.reshape(b, h * w, c)
    per_tap = kernel.reshape(k, c, -1).astype(x.dtype)
    out = None
    for t in range(k):
        mixed = _four_neighbours(flat, index[..., t], weight[..., t]) @ per_tap[t]
        out = mixed if out is None else out + mixed
    return out


def release_offsets(height: int, width: int, lat_min: float = -math.pi / 2,
                    lat_max: float = 0.0) -> np.ndarray:
    """(H, W, 9, 2) float64 offsets (dy, dx) in pixels, exactly as the release computes them.

    Tap k = 3 (i + 1) + (j + 1). ``deform_conv2d`` samples tap (i, j) of output pixel (y, x) at
    ``(y + i + dy, x + j + dx)``; see :func:`release_positions`. The release's construction:
    a gnomonic kernel with ``kx = tan(j dlon)``, ``ky = tan(i dlat) / cos(i dlon)`` mapped to
    latitude / longitude around each pixel centre, converted to pixels on a map spanning
    longitudes [0, 2 pi), wrapped with ``% (W - 1)`` and then ``% W``, and stored minus the
    pixel's own index (not minus the tap's kernel position).
    """
    lat_span = lat_max - lat_min
    lat_mid = lat_min + lat_span / 2
    lon_span, lon_mid = 2 * math.pi, math.pi
    dlat, dlon = lat_span / height, lon_span / width
    steps = np.array([-1.0, 0.0, 1.0])
    kx = np.tan(steps * dlon)
    ky = np.tan(steps * dlat) / np.cos(steps * dlon)
    ky, kx = np.meshgrid(ky, kx, indexing="ij")                      # (3, 3): [i, j]
    rho = np.sqrt(kx**2 + ky**2)
    rho[1, 1] = 1e-8  # the centre tap: the release's guard against 0 / 0
    nu = np.arctan(rho)
    lat_c = ((np.arange(height) + 0.5) / height - 0.5) * lat_span + lat_mid   # (H,)
    lon_c = ((np.arange(width) + 0.5) / width - 0.5) * lon_span + lon_mid     # (W,)
    sl, cl = np.sin(lat_c)[:, None, None], np.cos(lat_c)[:, None, None]
    lat = np.arcsin(np.cos(nu) * sl + ky * np.sin(nu) * cl / rho)             # (H, 3, 3)
    dlon_tap = np.arctan2(kx * np.sin(nu), rho * cl * np.cos(nu) - ky * sl * np.sin(nu))
    lon = dlon_tap[:, None] + lon_c[None, :, None, None]                       # (H, W, 3, 3)
    row = ((lat - lat_mid) / lat_span + 0.5) * height
    col = ((lon - lon_mid) / lon_span + 0.5) * width
    col = np.mod(np.mod(col, width - 1), width)
    dy = np.broadcast_to(row[:, None], col.shape) - np.arange(height)[:, None, None, None]
    dx = col - np.arange(width)[None, :, None, None]
    return np.stack([dy, dx], axis=-1).reshape(height, width, 9, 2)


def release_positions(offsets: np.ndarray) -> np.ndarray:
    """(H, W, 9, 2) (row, col) where ``deform_conv2d`` (3x3, stride 1, padding 1) samples each
    tap, from offsets (H, W, 9, 2) (dy, dx): ``(y - 1 + i + dy, x - 1 + j + dx)``."""
    height, width = offsets.shape[:2]
    i, j = np.meshgrid([0.0, 1.0, 2.0], [0.0, 1.0, 2.0], indexing="ij")
    rows = np.arange(height)[:, None, None] - 1 + i.reshape(1, 1, 9) + offsets[..., 0]
    cols = np.arange(width)[None, :, None] - 1 + j.reshape(1, 1, 9) + offsets[..., 1]
    return np.stack([rows, cols], axis=-1)


def zero_padded_tables(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gather indices (4, H, W, K) int32 and weights (4, H, W, K) float32 for bilinear
    sampling of an (H, W) map at ``positions`` (H, W, K, 2) = (row, col), every neighbour
    outside the map weighted 0 (``deform_conv2d`` / ``grid_sample`` zero padding)."""
    height, width = positions.shape[:2]
    rows, cols = positions[..., 0], positions[..., 1]
    r0, c0 = np.floor(rows), np.floor(cols)
    fr, fc = rows - r0, cols - c0
    r0, c0 = r0.astype(np.int64), c0.astype(np.int64)
    index = np.zeros((4,) + rows.shape, np.int32)
    weight = np.zeros((4,) + rows.shape, np.float32)
    for n, (dr, dc, w) in enumerate([(0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc),
                                     (1, 0, fr * (1 - fc)), (1, 1, fr * fc)]):
        r, c = r0 + dr, c0 + dc
        inside = (r >= 0) & (r < height) & (c >= 0) & (c < width)
        index[n] = np.clip(r, 0, height - 1) * width + np.clip(c, 0, width - 1)
        weight[n] = np.where(inside, w, 0.0)
    return index, weight


TAPS = ("release", "tangent")


@functools.lru_cache(maxsize=16)
def _cached_tables(taps: str, height: int, width: int, lat_min: float, lat_max: float):
    if taps == "release":
        return zero_padded_tables(release_positions(
            release_offsets(height, width, lat_min, lat_max)))
    return sampling_tables(tangent_offsets(height, width, lat_min, lat_max), width)


def transposed_tables(index: np.ndarray, weight: np.ndarray,
                      size: int) -> tuple[np.ndarray, np.ndarray]:
    """The transpose of a bilinear gather, as another gather.

    ``index`` (4, *S) flat source indices and ``weight`` (4, *S') broadcastable to S, as
    :func:`sampling_tables` or :func:`zero_padded_tables` give them, describe
    ``out[s] = sum_n weight[n, s] src[index[n, s]]`` over the flattened positions s of S.
    Returns ``t_index`` (size, M) int32 positions s and ``t_weight`` (size, M) float32 with
    ``src_grad[p] = sum_m t_weight[p, m] out_grad[t_index[p, m]]``, M the most reads of any
    source pixel; unused slots have weight 0. Entries of weight 0 are dropped.
    """
    idx = np.asarray(index).reshape(4, -1)
    w = np.broadcast_to(np.asarray(weight), np.shape(index)).reshape(4, -1)
    pos = np.broadcast_to(np.arange(idx.shape[1]), idx.shape)
    keep = w != 0
    src, dst, wt = idx[keep], pos[keep], w[keep]
    order = np.argsort(src, kind="stable")
    src, dst, wt = src[order], dst[order], wt[order]
    counts = np.bincount(src, minlength=size)
    slots = max(int(counts.max(initial=0)), 1)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(len(src)) - starts[src]
    t_index = np.zeros((size, slots), np.int32)
    t_weight = np.zeros((size, slots), np.float32)
    t_index[src, slot] = dst
    t_weight[src, slot] = wt
    return t_index, t_weight


@functools.lru_cache(maxsize=16)
def _fixed_tap_gather(taps: str, height: int, width: int, lat_min: float, lat_max: float):
    """:func:`gather_taps` on the cached tables, with a backward pass that gathers through
    :func:`transposed_tables` instead of scatter-adding (the autodiff transpose of a gather):
    on a CPU the scatter-add was five times the cost of this, and most of a training step's
    spherical conv."""
    index, weight = _cached_tables(taps, height, width, lat_min, lat_max)
    t_index, t_weight = transposed_tables(index, weight, height * width)

    @jax.custom_vjp
    def gather(x):
        return gather_taps(x, jnp.asarray(index), jnp.asarray(weight))

    def forward(x):
        return gather(x), None

    def backward(_, grad):
        b, h, w, k, c = grad.shape
        flat = grad.reshape(b, h * w * k, c)
        out = None
        # One slot at a time: a single gather of every slot is as slow as the scatter-add.
        for m in range(t_index.shape[1]):
            term = (jnp.take(flat, jnp.asarray(t_index[:, m]), axis=1)
                    * jnp.asarray(t_weight[:, m], grad.dtype)[None, :, None])
            out = term if out is None else out + term
        return (out.reshape(b, h, w, c),)

    gather.defvjp(forward, backward)
    return gather


class SphericalConv(nnx.Module):
    """3x3 spherical conv (C_in -> C_out, no bias) + BatchNorm + LeakyReLU on a fixed map size.

    ``__call__(x (B, H, W, C_in)) -> (B, H, W, C_out)``; H, W must equal the construction size.
    The map covers latitudes [lat_min, lat_max] (radians; default the hemisphere -90..0 deg with
    the pole at row 0) and the full longitude circle; ``taps`` is ``'release'`` or ``'tangent'``
    (module docstring).
    """

    def __init__(self, in_ch: int, out_ch: int, height: int, width: int, rngs: nnx.Rngs,
                 lat_min: float = -math.pi / 2, lat_max: float = 0.0, taps: str = "release"):
        if taps not in TAPS:
            raise ValueError(f"spherical taps must be one of {TAPS}; found {taps!r}")
        self.taps = taps
        self.height, self.width = height, width
        self.lat_range = (float(lat_min), float(lat_max))
        self.mix = nnx.Linear(9 * in_ch, out_ch, use_bias=False, kernel_init=kernel_init,
                              rngs=rngs)
        self.bn = batch_norm(out_ch, rngs)

    def __call__(self, x: Array) -> Array:
        if x.shape[1:3] != (self.height, self.width):
            raise ValueError(
                f"SphericalConv built for {self.height} x {self.width} feature maps, "
                f"got input of shape {tuple(x.shape)}"
            )
        # The tables are compile-time constants (cached numpy), neither parameters nor state,
        # so checkpoints hold only the weights.
        tables = (self.taps, self.height, self.width, *self.lat_range)
        if self.bn.use_running_average:
            # Inference (eval mode, also what is exported): tap by tap, the least memory and
            # the faster forward. Training keeps the stacked form, whose backward is faster.
            index, weight = _cached_tables(*tables)
            mixed = mix_taps_one_by_one(x, jnp.asarray(index), jnp.asarray(weight),
                                        self.mix.kernel[...])
        else:
            taps = _fixed_tap_gather(*tables)(x)
            b, h, w, k, c = taps.shape
            mixed = self.mix(taps.reshape(b, h, w, k * c))
        return leaky_relu(self.bn(mixed))
