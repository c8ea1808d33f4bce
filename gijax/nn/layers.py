"""Shared building blocks: conv + batch norm (+ LeakyReLU) and residual blocks, 2-D or 3-D.

Convolutions that feed a batch norm have no bias (the norm's shift replaces it). Padding is
explicit and symmetric, ``k // 2`` on each side (PyTorch's ``padding=k // 2``): a stride-2
conv on an even axis of length n then gives n / 2 outputs whose windows are centred on inputs
0, 2, 4, ... (XLA's 'SAME' would pad only at the end and centre them on 1, 3, 5, ...).
BatchNorm follows the module's train/eval mode (``model.train()`` / ``model.eval()``); its
momentum 0.9 is the PyTorch default 0.1 written the flax way.
"""

from __future__ import annotations

import contextlib
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

Array = jax.Array

LEAKY_SLOPE = 0.01
BN_MOMENTUM = 0.9
BN_EPSILON = 1e-5


_INIT_CHUNK = 1 << 16


def kernel_init(key: Array, shape, dtype=jnp.float32) -> Array:
    """LeCun-normal weights (truncated at 2 sigma, std 1 / sqrt(fan_in) after truncation),
    fan_in = product of all but the last axis: the flax default for Conv and Linear.

    The normals are drawn in fixed-size chunks (one key per chunk) and cut to size, so eager
    initialisation compiles the random-number program once instead of once per kernel shape
    (about 0.3-1.5 s of XLA compile time each on a CPU); when the draw is concrete the cut and
    scale run in numpy. Traced (jit / eval_shape) and eager initialisation give equal values.
    """
    n = math.prod(shape)
    std = 1.0 / math.sqrt(math.prod(shape[:-1])) / 0.87962566103423978
    m = -(-n // _INIT_CHUNK)
    keys = jax.random.split(key, m)

    def draw(k):
        return jax.random.truncated_normal(k, -2.0, 2.0, (_INIT_CHUNK,), dtype)

    if isinstance(keys, jax.core.Tracer):
        # One vmapped draw traces faster than m separate ones and gives the same numbers.
        z = jax.vmap(draw)(keys).reshape(-1)
        return z[:n].reshape(shape) * jnp.asarray(std, dtype)
    z = np.concatenate([np.asarray(draw(keys[i])) for i in range(m)])
    return jnp.asarray((z[:n].reshape(shape) * std).astype(dtype))


def leaky_relu(x: Array) -> Array:
    """LeakyReLU with the release's negative slope 0.01."""
    return jax.nn.leaky_relu(x, LEAKY_SLOPE)


def batch_norm(channels: int, rngs: nnx.Rngs) -> nnx.BatchNorm:
    return nnx.BatchNorm(channels, momentum=BN_MOMENTUM, epsilon=BN_EPSILON, rngs=rngs)


_CONV3D_MODES = ("auto", "native", "split")
_conv3d_mode = "auto"


@contextlib.contextmanager
def conv3d_mode(mode: str):
    """Choose how :class:`Conv3D` lowers while tracing inside this context.

    * ``'native'``: one 3-D convolution (cuDNN on GPUs; a single ONNX Conv node for export).
    * ``'split'``: 2-D convolutions over the depth-shifted slices (depth folded into the
      batch), summed per depth tap or stacked on the channel axis by plane size. Same numbers
      and parameters; on CPU, XLA has no fast 3-D convolution and this is 4-10x quicker forward
      and backward.
    * ``'auto'`` (default): 'split' on the CPU backend, 'native' elsewhere.

    The choice is made at trace time, so it must be in force when a function is first jitted.
    """
    global _conv3d_mode
    if mode not in _CONV3D_MODES:
        raise ValueError(f"conv3d mode must be one of {_CONV3D_MODES}, got {mode!r}")
    previous, _conv3d_mode = _conv3d_mode, mode
    try:
        yield
    finally:
        _conv3d_mode = previous


def _use_split() -> bool:
    if _conv3d_mode == "auto":
        return jax.default_backend() == "cpu"
    return _conv3d_mode == "split"


# Plane size (h * w * C_in elements) from which the split 3-D conv sums one 2-D conv per depth
# tap instead of stacking the taps on the channel axis (see Conv3D.__call__).
_SUM_OF_TAPS_MIN_PLANE = 1 << 18


class Conv3D(nnx.Conv):
    """3-D conv, channels-last (B, D, H, W, C), cubic kernel, symmetric padding ``kernel // 2``.

    An ``nnx.Conv`` (same parameters ``kernel`` (k, k, k, C_in, C_out) and optional ``bias``)
    whose lowering follows :func:`conv3d_mode`; the native path is ``nnx.Conv`` itself, which
    ONNX exporters map to one Conv node.
    """

    def __init__(self, in_ch: int, out_ch: int, kernel: int, stride: int, rngs: nnx.Rngs,
                 use_bias: bool = False):
        pad = kernel // 2
        super().__init__(
            in_ch, out_ch, (kernel,) * 3, strides=(stride,) * 3, padding=((pad, pad),) * 3,
            use_bias=use_bias, kernel_init=kernel_init, rngs=rngs,
        )
        self.size = kernel
        self.stride = stride

    def __call__(self, x: Array) -> Array:
        if not _use_split():
            return nnx.Conv.__call__(self, x)
        w = self.kernel[...].astype(x.dtype)
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

        def conv2d(planes, kernel):
            return jax.lax.conv_general_dilated(
                planes.reshape(b * d_out, h, width, planes.shape[-1]), kernel, (s, s),
                [(pad, pad)] * 2, dimension_numbers=("NHWC", "HWIO", "NHWC"))

        if h * width * c >= _SUM_OF_TAPS_MIN_PLANE:
            out = sum(conv2d(planes, w[t]) for t, planes in enumerate(slices))
        else:  # (k, k, k C_in, C_out) kernel, depth-tap-major input channels
            out = conv2d(jnp.concatenate(slices, axis=-1),
                         jnp.moveaxis(w, 0, 2).reshape(k, k, k * c, w.shape[-1]))
        out = out.reshape(b, d_out, *out.shape[1:])
        if self.bias is not None:
            out = out + self.bias[...].astype(out.dtype)
        return out


def conv(in_ch: int, out_ch: int, kernel: int, ndim: int, stride: int, rngs: nnx.Rngs,
         use_bias: bool = False) -> nnx.Module:
    """A ``ndim``-D conv, cubic kernel ``kernel``, symmetric padding ``kernel // 2``."""
    if ndim == 3:
        return Conv3D(in_ch, out_ch, kernel, stride, rngs, use_bias)
    pad = kernel // 2
    return nnx.Conv(
        in_ch, out_ch, (kernel,) * ndim, strides=(stride,) * ndim,
        padding=((pad, pad),) * ndim, use_bias=use_bias, kernel_init=kernel_init, rngs=rngs,
    )


class ConvBN(nnx.Module):
    """conv (no bias) -> BatchNorm -> optional LeakyReLU; channels-last, 2-D or 3-D."""

    def __init__(self, in_ch: int, out_ch: int, kernel: int, ndim: int, rngs: nnx.Rngs,
                 stride: int = 1, activate: bool = True):
        self.conv = conv(in_ch, out_ch, kernel, ndim, stride, rngs)
        self.bn = batch_norm(out_ch, rngs)
        self.activate = activate

    def __call__(self, x: Array) -> Array:
        y = self.bn(self.conv(x))
        return leaky_relu(y) if self.activate else y


class ResidualBlock(nnx.Module):
    """x + BN(conv3(LeakyReLU(BN(conv3(x))))) followed by LeakyReLU; shape-preserving."""

    def __init__(self, channels: int, ndim: int, rngs: nnx.Rngs):
        self.first = ConvBN(channels, channels, 3, ndim, rngs)
        self.second = ConvBN(channels, channels, 3, ndim, rngs, activate=False)

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
