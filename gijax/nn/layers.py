"""Shared building blocks: conv + batch norm (+ LeakyReLU) and residual blocks, 2-D or 3-D.

Convolutions that feed a batch norm have no bias (the norm's shift replaces it). Padding is
explicit and symmetric, ``k // 2`` on each side (PyTorch's ``padding=k // 2``): a stride-2
conv on an even axis of length n then gives n / 2 outputs whose windows are centred on inputs
0, 2, 4, ... (XLA's 'SAME' would pad only at the end and centre them on 1, 3, 5, ...).
BatchNorm follows the module's train/eval mode (``model.train()`` / ``model.eval()``); its
momentum 0.9 is the PyTorch default 0.1 written the flax way.

Every conv and linear kernel is drawn by :func:`kernel_init`, the only random initialiser in
the network: a module built eagerly or under ``jax.jit`` holds the same weights for the same
``nnx.Rngs`` seed.

How a 3-D conv lowers to XLA is a constructor argument (``lowering`` of :class:`Conv3D`,
``conv3d`` of the modules that hold one), hence part of the module graph that ``nnx.jit`` and
``nnx.split`` see: a function traced for one lowering is never reused for another.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

Array = jax.Array

LEAKY_SLOPE = 0.01
BN_MOMENTUM = 0.9
BN_EPSILON = 1e-5

# Standard deviation of a unit normal truncated to [-2, 2]: kernels are divided by it so that
# their variance stays 1 / fan_in after the truncation.
TRUNCATED_NORMAL_STD = 0.87962566103423978

# Normals are drawn in chunks of this many values, so that every kernel shape uses the same
# random-number program.
_INIT_CHUNK = 1 << 16


def kernel_init(key: Array, shape, dtype=jnp.float32) -> Array:
    """LeCun-normal weights: a normal truncated at 2 sigma, rescaled to std 1 / sqrt(fan_in),
    fan_in = product of all but the last axis (flax's default for Conv and Linear).

    Chunk ``i`` of ``2**16`` normals is drawn from ``fold_in(key, i)`` and the chunks are cut to
    ``shape``. Why: eagerly, XLA compiles one program per distinct random-array shape (0.3-1.5 s
    of CPU compile time each), which made building a paper-size network take about a minute;
    with a fixed chunk shape, and a key per chunk that needs no shape-dependent split, the two
    programs (``fold_in`` and the draw) compile once per process. Concrete draws are cut and
    scaled in numpy for the same reason. Traced (jit, ``nnx.eval_shape``) the chunks are one
    vmapped draw of the same numbers.
    """
    n = math.prod(shape)
    std = 1.0 / math.sqrt(math.prod(shape[:-1])) / TRUNCATED_NORMAL_STD
    chunks = -(-n // _INIT_CHUNK)

    def draw(i):
        return jax.random.truncated_normal(jax.random.fold_in(key, i), -2.0, 2.0,
                                           (_INIT_CHUNK,), dtype)

    # Ask the first draw, not the key, whether this is traced: a concrete key closed over by a
    # traced function still gives traced draws.
    draws = [draw(np.uint32(0))]
    if isinstance(draws[0], jax.core.Tracer):
        z = jax.vmap(draw)(jnp.arange(chunks, dtype=jnp.uint32)).reshape(-1)
        return z[:n].reshape(shape) * jnp.asarray(std, dtype)
    # All chunks are dispatched before the first is read back, so the draws overlap the copies.
    draws += [draw(np.uint32(i)) for i in range(1, chunks)]
    z = np.concatenate([np.asarray(d) for d in draws])
    return jnp.asarray((z[:n].reshape(shape) * std).astype(dtype))


def leaky_relu(x: Array) -> Array:
    """LeakyReLU with the release's negative slope 0.01."""
    return jax.nn.leaky_relu(x, LEAKY_SLOPE)


def batch_norm(channels: int, rngs: nnx.Rngs) -> nnx.BatchNorm:
    return nnx.BatchNorm(channels, momentum=BN_MOMENTUM, epsilon=BN_EPSILON, rngs=rngs)


CONV3D_LOWERINGS = ("auto", "split", "native")


def _use_split(lowering: str) -> bool:
    # 'auto' is resolved while tracing, by the backend the program is compiled for.
    if lowering == "auto":
        return jax.default_backend() == "cpu"
    return lowering == "split"


# Plane size (h * w * C_in elements) from which the split 3-D conv sums one 2-D conv per depth
# tap instead of stacking the taps on the channel axis (see Conv3D.__call__).
_SUM_OF_TAPS_MIN_PLANE = 1 << 18


def tap_sum_2d(z: Array) -> Array:
    """(N, H, W, k*k) -> (N, H, W, 1): ``y[n, h, w] = sum_t z[n, h + j_t - p, w + l_t - p, t]``,
    tap ``t = j_t k + l_t``, ``p = k // 2``, zero outside the map. With ``z = x @ W`` (a
    kernel's k*k taps as columns) this is the 2-D conv ``x * W`` with one output channel,
    ``same`` padding.

    Computed as a fixed 2-D conv with a one-hot kernel, whose autodiff transpose is one pass
    (written as k*k shifted slices summed, the transpose pads each slice to the whole of ``z``
    and adds k*k such arrays: 0.5 s for a batch-8 CPU volume; and XLA's CPU backend, with its
    optimisations off and the classic emitters, evaluated that form inexactly in float64).
    """
    k, p = _tap_kernel(z)
    one_hot = jnp.eye(k * k, dtype=z.dtype).reshape(k, k, k * k, 1)
    return jax.lax.conv_general_dilated(z, one_hot, (1, 1), [(p, p)] * 2,
                                        dimension_numbers=("NHWC", "HWIO", "NHWC"))


def _tap_kernel(z: Array) -> tuple[int, int]:
    k = math.isqrt(z.shape[-1])
    if k * k != z.shape[-1] or k % 2 == 0:
        raise ValueError(f"tap_sum_2d takes k*k tap channels, k odd; found {z.shape[-1]}")
    return k, k // 2


# Input channels from which a stride-1 conv with one output channel is computed by
# :func:`_one_output_conv3d` (batch-8 CPU volume, forward + both gradients: 24 -> 1 52 against
# 140 ms, 16 -> 1 31 against 57 ms, 8 -> 1 34 against 23 ms).
_ONE_OUTPUT_MIN_CHANNELS = 16


def _one_output_conv3d(x: Array, w: Array) -> Array:
    """Stride-1 3-D conv (B, D, H, W, C) * (k, k, k, C, 1) -> (B, D, H, W, 1), ``same``
    padding: per depth tap one matrix product to the k*k spatial taps' contributions, summed
    over the taps by :func:`tap_sum_2d`. A 3 x 3 x 3, 24 -> 1 conv on a batch-8 CPU-scale
    volume (the concat presets' U-Net head), forward, input and weight gradients: 52 ms,
    against 140 ms as a 2-D conv over stacked depth taps, whose weight gradient XLA's CPU
    backend runs slowly at one output channel."""
    k, p = w.shape[0], w.shape[0] // 2
    b, d, h, width, c = x.shape
    xp = jnp.pad(x, ((0, 0), (p, p), (0, 0), (0, 0), (0, 0)))
    y = None
    for i in range(k):
        taps = w[i, ..., 0].reshape(k * k, c).T                            # (C, k*k)
        z = jnp.einsum("bdhwc,ct->bdhwt", xp[:, i:i + d], taps)
        term = tap_sum_2d(z.reshape(b * d, h, width, k * k))
        y = term if y is None else y + term
    return y.reshape(b, d, h, width, 1)


class Conv3D(nnx.Conv):
    """3-D conv, channels-last (B, D, H, W, C), cubic kernel, symmetric padding ``kernel // 2``.

    An ``nnx.Conv`` (same parameters ``kernel`` (k, k, k, C_in, C_out) and optional ``bias``)
    with a choice of lowering, ``lowering``, that changes neither the parameters nor the numbers:

    * ``'native'``: ``nnx.Conv`` itself, one 3-D convolution (cuDNN on GPUs; one ONNX Conv node
      per layer, which is what the exporter needs).
    * ``'split'``: 2-D convolutions over depth-shifted slices with the depth folded into the
      batch. XLA's CPU backend has no fast 3-D convolution; this is 4-10x quicker there,
      forward and backward. A stride-1 conv with one output channel and 16 or more input
      channels (the concat presets' U-Net head) is matrix products and shifted sums instead
      (:func:`tap_sum_2d`).
    * ``'auto'``: 'split' when compiling for the CPU backend, 'native' otherwise.
    """

    def __init__(self, in_ch: int, out_ch: int, kernel: int, stride: int, rngs: nnx.Rngs,
                 use_bias: bool = False, lowering: str = "auto"):
        if lowering not in CONV3D_LOWERINGS:
            raise ValueError(f"conv3d lowering must be one of {CONV3D_LOWERINGS}; "
                             f"found {lowering!r}")
        pad = kernel // 2
        super().__init__(
            in_ch, out_ch, (kernel,) * 3, strides=(stride,) * 3, padding=((pad, pad),) * 3,
            use_bias=use_bias, kernel_init=kernel_init, rngs=rngs,
        )
        self.size = kernel
        self.stride = stride
        self.lowering = lowering

    def __call__(self, x: Array) -> Array:
        if not _use_split(self.lowering):
            return nnx.Conv.__call__(self, x)
        w = self.kernel[...].astype(x.dtype)
        head = w.shape[-1] == 1 and self.stride == 1
        if head and x.shape[-1] >= _ONE_OUTPUT_MIN_CHANNELS:
            out = _one_output_conv3d(x, w)
        else:
            out = self._stacked_or_summed_taps(x, w)
        if self.bias is not None:
            out = out + self.bias[...].astype(out.dtype)
        return out

    def _stacked_or_summed_taps(self, x: Array, w: Array) -> Array:
        """The split lowering of any conv, without its bias."""
        k, s, pad = self.size, self.stride, self.size // 2
        b, d, h, width, c = x.shape
        d_out = (d + 2 * pad - k) // s + 1
        xp = jnp.pad(x, ((0, 0), (pad, pad), (0, 0), (0, 0), (0, 0)))
        # Depth tap t reads input planes t, t + s, ..., one per output plane, and the 3-D conv
        # is a 2-D conv over depth folded into the batch, in one of two equal forms. On XLA's
        # CPU backend, for large planes a sum of k 2-D convs (one per depth tap, (k, k, C_in,
        # C_out) kernels) is fastest: 1.5x on the paper-size U-Net's first stage, where the
        # other form copies k times its input. For small planes (the CPU presets) one 2-D conv
        # over the k taps stacked on the channel axis is faster (1.4x on their U-Nets).
        slices = [jax.lax.slice_in_dim(xp, t, t + s * (d_out - 1) + 1, stride=s, axis=1)
                  for t in range(k)]
        # XLA's CPU weight gradient of these 2-D convs is several times slower at 24 output
        # channels than at 32 (the concat CPU presets' cost volume and last U-Net stage: the
        # backward of a 72 -> 24 conv on a batch-8 volume 419 ms, with the kernel padded to 32
        # output channels and the result sliced 168 ms). Same values up to float rounding.
        out_ch = w.shape[-1]
        pad_out = 8 if out_ch > 8 and out_ch % 16 == 8 else 0
        if pad_out:
            w = jnp.pad(w, ((0, 0),) * 4 + ((0, pad_out),))

        def conv2d(planes, kernel):
            return jax.lax.conv_general_dilated(
                planes.reshape(b * d_out, h, width, planes.shape[-1]), kernel, (s, s),
                [(pad, pad)] * 2, dimension_numbers=("NHWC", "HWIO", "NHWC"))

        if h * width * c >= _SUM_OF_TAPS_MIN_PLANE:
            out = sum(conv2d(planes, w[t]) for t, planes in enumerate(slices))
        else:  # (k, k, k C_in, C_out) kernel, depth-tap-major input channels
            out = conv2d(jnp.concatenate(slices, axis=-1),
                         jnp.moveaxis(w, 0, 2).reshape(k, k, k * c, w.shape[-1]))
        return out.reshape(b, d_out, *out.shape[1:])[..., :out_ch]


def conv(in_ch: int, out_ch: int, kernel: int, ndim: int, stride: int, rngs: nnx.Rngs,
         use_bias: bool = False, conv3d: str = "auto") -> nnx.Module:
    """A ``ndim``-D conv, cubic kernel ``kernel``, symmetric padding ``kernel // 2``; a 3-D one
    lowers as ``conv3d`` (see :class:`Conv3D`)."""
    if ndim == 3:
        return Conv3D(in_ch, out_ch, kernel, stride, rngs, use_bias, lowering=conv3d)
    pad = kernel // 2
    return nnx.Conv(
        in_ch, out_ch, (kernel,) * ndim, strides=(stride,) * ndim,
        padding=((pad, pad),) * ndim, use_bias=use_bias, kernel_init=kernel_init, rngs=rngs,
    )


class ConvBN(nnx.Module):
    """conv (no bias) -> BatchNorm -> optional LeakyReLU; channels-last, 2-D or 3-D."""

    def __init__(self, in_ch: int, out_ch: int, kernel: int, ndim: int, rngs: nnx.Rngs,
                 stride: int = 1, activate: bool = True, conv3d: str = "auto"):
        self.conv = conv(in_ch, out_ch, kernel, ndim, stride, rngs, conv3d=conv3d)
        self.bn = batch_norm(out_ch, rngs)
        self.activate = activate

    def __call__(self, x: Array) -> Array:
        y = self.bn(self.conv(x))
        return leaky_relu(y) if self.activate else y


class ResidualBlock(nnx.Module):
    """x + BN(conv3(LeakyReLU(BN(conv3(x))))) followed by LeakyReLU; shape-preserving."""

    def __init__(self, channels: int, ndim: int, rngs: nnx.Rngs, conv3d: str = "auto"):
        self.first = ConvBN(channels, channels, 3, ndim, rngs, conv3d=conv3d)
        self.second = ConvBN(channels, channels, 3, ndim, rngs, activate=False, conv3d=conv3d)

    def __call__(self, x: Array) -> Array:
        return leaky_relu(x + self.second(self.first(x)))


def param_count(module: nnx.Module) -> int:
    """Number of trainable scalars (``nnx.Param``) in ``module``; BatchNorm running statistics
    are not counted. Works on abstract modules built under ``nnx.eval_shape``."""
    leaves = jax.tree_util.tree_leaves(nnx.state(module, nnx.Param))
    total = 0
    for leaf in leaves:
        size = 1
        for s in leaf.shape:
            size *= s
        total += size
    return total
