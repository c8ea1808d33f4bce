"""Photometric degradations of rendered images: what a real camera does to the light.

The renderer's images are noiseless, perfectly sharp, evenly exposed and losslessly stored; a
real fisheye is none of these. Each function here is pure and traceable (``jit``, ``vmap``) and
works on one camera's float RGB image (H, W, 3) in [0, 1] (channels-last, the model's layout)
with scalar or per-channel parameters; :func:`gijax.data.augment.augment_sample` draws the
parameters and maps them over the cameras of a sample.

Parameter ranges given below are the ones the training presets draw from
(:class:`gijax.data.augment.AugmentConfig`); the functions themselves accept any value.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

Array = jax.Array


# -- sensor noise


def noise_variance(image: Array, shot_gain, read_std) -> Array:
    """Per-pixel variance of the heteroscedastic (Poisson-Gaussian) sensor model:
    ``shot_gain * x + read_std**2`` for signal ``x`` (shot noise grows with the signal, read
    noise does not)."""
    return shot_gain * jnp.clip(image, 0.0, None) + jnp.square(read_std)


def sensor_noise(key: Array, image: Array, shot_gain, read_std) -> Array:
    """Add zero-mean Gaussian noise of :func:`noise_variance` to every pixel and channel, then
    clip to [0, 1].

    The Gaussian with signal-dependent variance is the standard approximation of photon (shot)
    noise plus read noise at the photon counts of a daylight exposure. Ranges drawn in
    training: ``shot_gain`` 1e-4 .. 3e-3 (1/photons per full-scale unit: a 0.5 grey then has
    shot noise standard deviation 0.007 .. 0.04), ``read_std`` 0.002 .. 0.01.
    """
    std = jnp.sqrt(noise_variance(image, shot_gain, read_std))
    noisy = image + std * jax.random.normal(key, image.shape, image.dtype)
    return jnp.clip(noisy, 0.0, 1.0)


# -- blur


def gaussian_kernel(sigma, radius: int) -> Array:
    """The normalised 1-D Gaussian ``exp(-k^2 / (2 sigma^2))``, k = -radius..radius (OpenCV's
    ``getGaussianKernel`` for ``ksize = 2 radius + 1``). ``radius`` is static (a Python int) so
    that ``sigma`` may be traced; ``sigma`` is floored at 1e-3 (a delta kernel)."""
    k = jnp.arange(-radius, radius + 1, dtype=jnp.float32)
    s = jnp.maximum(jnp.asarray(sigma, jnp.float32), 1e-3)
    w = jnp.exp(-0.5 * jnp.square(k / s))
    return w / jnp.sum(w)


def _filter_axis(image: Array, kernel: Array, axis: int) -> Array:
    # A sum of shifted copies: exact, traceable with a traced kernel, and cheap for the few
    # taps a small blur needs. Reflect-101 padding is OpenCV's default border.
    radius = (kernel.shape[0] - 1) // 2
    pad = [(0, 0)] * image.ndim
    pad[axis] = (radius, radius)
    padded = jnp.pad(image, pad, mode="reflect")
    n = image.shape[axis]
    taps = [jax.lax.slice_in_dim(padded, i, i + n, axis=axis) for i in range(kernel.shape[0])]
    return sum(kernel[i] * t for i, t in enumerate(taps))


def gaussian_blur(image: Array, sigma, radius: int) -> Array:
    """Separable Gaussian blur of an (H, W, C) image with standard deviation ``sigma`` pixels
    and a (2 radius + 1)-tap kernel, reflect-101 borders (equals OpenCV's ``GaussianBlur``).

    A Gaussian stands in for the small defocus and lens softness of a real fisheye (its point
    spread function is a few pixels wide and smooth). Range drawn in training: ``sigma``
    0.3 .. 1.2 px, ``radius`` = ceil(3 * largest sigma).
    """
    kernel = gaussian_kernel(sigma, radius).astype(image.dtype)
    return _filter_axis(_filter_axis(image, kernel, 0), kernel, 1)


# -- exposure, white balance, gamma


def exposure_white_balance(image: Array, exposure, gains, gamma) -> Array:
    """``clip(image * exposure * gains, 0, 1) ** gamma`` with per-channel ``gains`` (3,).

    Exposure and white balance are multiplicative per channel (the camera's analogue gain and
    its colour correction); ``gamma`` stands for a different tone curve. Ranges drawn in
    training: ``exposure`` 0.6 .. 1.6 (log-uniform), red and blue ``gains`` 0.85 .. 1.15 with
    green 1, ``gamma`` 0.8 .. 1.25 (log-uniform).
    """
    linear = jnp.clip(image * (exposure * jnp.asarray(gains, image.dtype)), 0.0, 1.0)
    # x ** gamma has an infinite slope at 0 for gamma < 1; the floor only touches black.
    return jnp.where(linear > 0, jnp.power(jnp.maximum(linear, 1e-12), gamma), 0.0)


# -- vignetting


def vignetting_factor(height: int, width: int, centre, radius, strength) -> Array:
    """The (H, W) light falloff ``1 / (1 + strength * (r / radius)^2)^2`` at pixel centres, r
    the distance to ``centre`` (u, v) in pixels.

    For a pinhole lens with ``radius`` = focal length and strength 1 this is the cos^4 law
    (cos(theta) = 1 / sqrt(1 + tan^2(theta))); for a fisheye it is a smooth radial falloff
    whose value at ``radius`` (half the shorter image side, the image circle) is
    ``1 / (1 + strength)^2``. Range drawn in training: ``strength`` 0 .. 0.6 (the image circle
    edge keeps 100 % .. 39 % of its light).
    """
    v = jnp.arange(height, dtype=jnp.float32)[:, None]
    u = jnp.arange(width, dtype=jnp.float32)[None, :]
    centre = jnp.asarray(centre, jnp.float32)
    r2 = (jnp.square(u - centre[0]) + jnp.square(v - centre[1])) / jnp.square(radius)
    return 1.0 / jnp.square(1.0 + strength * r2)


def vignetting(image: Array, centre, radius, strength) -> Array:
    """The image times :func:`vignetting_factor` around the principal point ``centre``."""
    h, w = image.shape[:2]
    return image * vignetting_factor(h, w, centre, radius, strength)[..., None].astype(image.dtype)


# -- JPEG-like compression: 8 x 8 block DCT quantisation

# The JPEG standard's (ITU-T T.81, annex K) example tables, the ones libjpeg scales by quality.
LUMA_TABLE = np.array([
    [16, 11, 10, 16, 24, 40, 51, 61], [12, 12, 14, 19, 26, 58, 60, 55],
    [14, 13, 16, 24, 40, 57, 69, 56], [14, 17, 22, 29, 51, 87, 80, 62],
    [18, 22, 37, 56, 68, 109, 103, 77], [24, 35, 55, 64, 81, 104, 113, 92],
    [49, 64, 78, 87, 103, 121, 120, 101], [72, 92, 95, 98, 112, 100, 103, 99]], np.float32)
CHROMA_TABLE = np.array([
    [17, 18, 24, 47, 99, 99, 99, 99], [18, 21, 26, 66, 99, 99, 99, 99],
    [24, 26, 56, 99, 99, 99, 99, 99], [47, 66, 99, 99, 99, 99, 99, 99],
    [99, 99, 99, 99, 99, 99, 99, 99], [99, 99, 99, 99, 99, 99, 99, 99],
    [99, 99, 99, 99, 99, 99, 99, 99], [99, 99, 99, 99, 99, 99, 99, 99]], np.float32)
BLOCK = 8


def dct_matrix(n: int = BLOCK) -> np.ndarray:
    """The orthonormal DCT-II matrix C (n, n): ``C @ x`` is ``scipy.fft.dct(x, norm='ortho')``."""
    k = np.arange(n)[:, None]
    i = np.arange(n)[None, :]
    c = np.cos(np.pi * (2 * i + 1) * k / (2 * n)) * math.sqrt(2.0 / n)
    c[0] /= math.sqrt(2.0)
    return c.astype(np.float32)


def quality_table(table, quality) -> Array:
    """libjpeg's scaling of a quantisation table to ``quality`` in 1..100 (traceable): scale
    ``5000 / q`` below 50 and ``200 - 2 q`` above, entries ``floor((T scale + 50) / 100)``
    clipped to 1..255."""
    q = jnp.clip(jnp.asarray(quality, jnp.float32), 1.0, 100.0)
    scale = jnp.where(q < 50, 5000.0 / q, 200.0 - 2.0 * q)
    return jnp.clip(jnp.floor((jnp.asarray(table, jnp.float32) * scale + 50.0) / 100.0), 1, 255)


def block_dct_quantise(plane: Array, table: Array) -> Array:
    """Quantise one level-shifted plane (H, W) (values in -128..127) the way JPEG does: the
    orthonormal 2-D DCT of every 8 x 8 block, each coefficient rounded to a multiple of its
    ``table`` entry, inverse DCT. H and W must be multiples of 8."""
    h, w = plane.shape
    c = jnp.asarray(dct_matrix(), plane.dtype)
    blocks = plane.reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK).transpose(0, 2, 1, 3)
    coeffs = c @ blocks @ c.T
    table = jnp.asarray(table, plane.dtype)
    quantised = jnp.round(coeffs / table) * table
    back = c.T @ quantised @ c
    return back.transpose(0, 2, 1, 3).reshape(h, w)


# JPEG's full-range YCbCr (JFIF), on values in 0..255.
_RGB_TO_YCC = np.array([[0.299, 0.587, 0.114],
                        [-0.168736, -0.331264, 0.5],
                        [0.5, -0.418688, -0.081312]], np.float32)


def jpeg_compress(image: Array, quality) -> Array:
    """JPEG's lossy step on an (H, W, 3) RGB image: to YCbCr, 8 x 8 block DCT quantisation of
    each plane with the standard tables scaled to ``quality`` (luma table for Y, chroma table
    for Cb and Cr), back to RGB, rounded to 8 bits and clipped to [0, 1].

    This is exactly what JPEG does to the signal; the entropy coding it skips is lossless.
    Chroma is not subsampled (4:4:4). Edges are padded by replication to a multiple of 8, as
    encoders do. Range drawn in training: ``quality`` 40 .. 95.
    """
    h, w = image.shape[:2]
    ph, pw = -h % BLOCK, -w % BLOCK
    x = jnp.pad(image.astype(jnp.float32) * 255.0, ((0, ph), (0, pw), (0, 0)), mode="edge")
    ycc = x @ jnp.asarray(_RGB_TO_YCC).T + jnp.array([0.0, 128.0, 128.0])
    luma, chroma = quality_table(LUMA_TABLE, quality), quality_table(CHROMA_TABLE, quality)
    planes = [block_dct_quantise(ycc[..., i] - 128.0, t) + 128.0
              for i, t in enumerate((luma, chroma, chroma))]
    ycc = jnp.stack(planes, -1) - jnp.array([0.0, 128.0, 128.0])
    rgb = ycc @ jnp.asarray(np.linalg.inv(_RGB_TO_YCC)).T
    rgb = jnp.clip(jnp.round(rgb), 0.0, 255.0) / 255.0
    return rgb[:h, :w].astype(image.dtype)
