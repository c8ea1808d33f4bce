"""Network modules: presets and parameter counts, cost volumes, U-Net, regressor, spherical conv.

References are independent: parameter counts re-derived by hand from REFERENCE section 4,
numpy loops for the masked variance, the interpolation formula for align_corners=False
upsampling, closed-form tangent-plane geometry, and XLA's own convolutions.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from hypothesis import given, settings
from hypothesis import strategies as st

from gijax.nn import (
    PRESETS,
    REFERENCE_PARAM_COUNTS,
    ConcatCostVolume,
    FeatureExtractor,
    ModelConfig,
    UNet3D,
    VarianceCostVolume,
    get_preset,
    masked_variance,
    regress,
    tangent_offsets,
    upsample2,
)
from gijax.model import OmniStereoNet, count_parameters
from gijax.nn.layers import Conv3D, kernel_init, tap_sum_2d
from gijax.nn.spherical import gather_taps, sampling_tables
from gijax.sampling import bilinear_sample

PAPER = ["E8", "G8", "E16", "G16", "G16V", "G16V-released", "G16VV"]


# ----------------------------------------------------------------------------- presets


def _hand_count(cin_unet: int, f: int, cost_in: int, c: int = 16, blocks=(5, 10)) -> int:
    """Trainable parameters from REFERENCE section 4's description, counted by hand.

    Convs before a norm have no bias; a BatchNorm has 2 C parameters.
    """
    k2, k3 = 9, 27
    bn = lambda ch: 2 * ch  # noqa: E731
    res2 = 2 * (k2 * c * c + bn(c))
    features = 25 * 3 * c + bn(c) + blocks[0] * res2 + k2 * c * c + bn(c) + blocks[1] * res2 \
        + k2 * c * c + bn(c)
    cost = k3 * cost_in * cin_unet + bn(cin_unet)
    res3 = lambda ch: 2 * (k3 * ch * ch + bn(ch))  # noqa: E731
    down = sum(k3 * a * b + bn(b) + 3 * res3(b) for a, b in [(cin_unet, f), (f, 2 * f),
                                                              (2 * f, 4 * f)])
    up = sum(k3 * a * b + bn(b) for a, b in [(4 * f, 2 * f), (2 * f, f), (f, cin_unet)])
    head = k3 * cin_unet + 1
    return features + cost + down + up + head


@pytest.fixture(scope="module")
def paper_counts():
    return {name: count_parameters(name)["total"] for name in PAPER}


def test_paper_parameter_counts_match_reference(paper_counts):
    for name in PAPER:
        ref = REFERENCE_PARAM_COUNTS[name]
        assert abs(paper_counts[name] / ref - 1) < 0.02, (name, paper_counts[name], ref)
    # The literal REFERENCE figures, not only the table in the code.
    assert abs(paper_counts["G16"] / 36.7e6 - 1) < 0.02
    assert abs(paper_counts["G16V-released"] / 4.15e6 - 1) < 0.02
    assert abs(paper_counts["G16VV"] / 36.5e6 - 1) < 0.02
    # Exact agreement with the hand count of the described architecture.
    assert paper_counts["G16"] == _hand_count(48, 96, 48)
    assert paper_counts["G16V-released"] == _hand_count(16, 32, 16)
    assert paper_counts["G16VV"] == _hand_count(16, 96, 16)
    # The released G16V's own count (its state dict's trainable entries, as the release's
    # parity fixtures record it).
    assert paper_counts["G16V-released"] == 4_150_977


def test_cpu_presets_keep_structure_and_validate():
    for name in PAPER:
        paper, cpu = PRESETS[name], PRESETS[name + "-cpu"]
        for field in ("num_candidates", "candidates", "loss", "features", "cost_volume",
                      "num_cameras", "mask_augmentation", "d_min", "d_max"):
            assert getattr(paper, field) == getattr(cpu, field), (name, field)
        assert cpu.surrogate_hw == (128, 512) and cpu.cost_hw == (16, 64)
        assert cpu.output_hw == (32, 128) and cpu.image_scale == 0.25
        assert count_parameters(cpu)["total"] < 3e6
    assert get_preset("G16VV").features == "spherical"
    assert get_preset("G16V").cost_volume == "concat"
    with pytest.raises(ValueError, match="G16VV-cpu"):
        get_preset("G32")
    base = get_preset("G16-cpu")
    with pytest.raises(ValueError, match="num_candidates"):
        dataclasses.replace(base, num_candidates=12)
    with pytest.raises(ValueError, match="cost_hw"):
        dataclasses.replace(base, cost_hw=(20, 64), output_hw=(40, 128))
    with pytest.raises(ValueError, match="unet_in"):
        dataclasses.replace(base, unet_in=8)
    with pytest.raises(ValueError, match="output_hw"):
        dataclasses.replace(base, output_hw=(16, 64))
    with pytest.raises(ValueError, match="loss"):
        dataclasses.replace(base, loss="l2")
    with pytest.raises(ValueError, match="conv3d"):
        dataclasses.replace(base, conv3d="fast")
    assert base.conv3d == "auto"
    assert isinstance(hash(base), int)  # usable as a jit static argument
    with pytest.raises(ValueError, match="output_stride"):
        dataclasses.replace(base, output_stride=4)
    # gijax's designs: the G16VV-cpu network with its cost volume at the output's size, or
    # with 32 candidates; the same parameters in both (every resized part is convolutional).
    fine, g32, g16vv = get_preset("G16VV-cpu-fine"), get_preset("G32VV-cpu"), PRESETS["G16VV-cpu"]
    assert fine.cost_hw == fine.output_hw == (32, 128) and fine.output_stride == 1
    assert g32.num_candidates == 32 and g32.cost_hw == (16, 64)
    assert (dataclasses.replace(fine, name=g16vv.name, cost_hw=(16, 64), output_stride=2)
            == dataclasses.replace(g32, name=g16vv.name, num_candidates=16) == g16vv)
    assert all(c.output_stride == 2 for n, c in PRESETS.items() if n in PAPER)


# ----------------------------------------------------------------------------- cost volumes


def _np_variance(f: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Loop reference: (B, N, D, h, w, C), (B, N, D, h, w) -> (B, D, h, w, C)."""
    b, n, d, h, w, c = f.shape
    out = np.zeros((b, d, h, w, c))
    for idx in np.ndindex(b, d, h, w):
        sel = [f[idx[0], k, idx[1], idx[2], idx[3]] for k in range(n)
               if v[idx[0], k, idx[1], idx[2], idx[3]] > 0]
        if len(sel) >= 2:
            sel = np.array(sel, np.float64)
            out[idx] = ((sel - sel.mean(0)) ** 2).mean(0)
    return out


@settings(max_examples=20, deadline=None)
@given(n=st.integers(2, 4), seed=st.integers(0, 10_000), p_valid=st.floats(0.2, 1.0))
def test_masked_variance_matches_numpy(n, seed, p_valid):
    rng = np.random.default_rng(seed)
    f = rng.normal(size=(1, n, 2, 2, 3, 2)).astype(np.float32)
    v = rng.random((1, n, 2, 2, 3)) < p_valid
    got = np.asarray(masked_variance(jnp.asarray(f), jnp.asarray(v)))
    np.testing.assert_allclose(got, _np_variance(f, v), rtol=1e-5, atol=1e-6)
    few = v.sum(1) < 2
    assert np.all(got[few] == 0.0)


@settings(max_examples=20, deadline=None)
@given(n=st.integers(2, 4), seed=st.integers(0, 10_000), p_valid=st.floats(0.2, 1.0))
def test_masked_variance_gradient_is_the_closed_form(n, seed, p_valid):
    # d/df_k of the population variance over the valid cameras is 2 (f_k - mean) / count for a
    # valid camera and 0 for the others; 0 everywhere in cells with fewer than 2 valid cameras.
    rng = np.random.default_rng(seed)
    f = rng.normal(size=(1, n, 2, 2, 3, 2))
    v = rng.random((1, n, 2, 2, 3)) < p_valid
    cot = rng.normal(size=(1, 2, 2, 3, 2))
    got = jax.grad(lambda x: jnp.sum(masked_variance(x, jnp.asarray(v)) * cot))(
        jnp.asarray(f, jnp.float32))
    count = v.sum(1, keepdims=True)[..., None]
    mean = (f * v[..., None]).sum(1, keepdims=True) / np.maximum(count, 1)
    want = np.where(count >= 2, 2 * (f - mean) * v[..., None] / np.maximum(count, 1), 0.0)
    np.testing.assert_allclose(np.asarray(got), want * cot[:, None], rtol=1e-5, atol=1e-6)
    # Forward mode too (jvp): the directional derivative along a random tangent.
    tangent = rng.normal(size=f.shape)
    _, d_var = jax.jvp(lambda x: masked_variance(x, jnp.asarray(v)),
                       (jnp.asarray(f, jnp.float32),), (jnp.asarray(tangent, jnp.float32),))
    np.testing.assert_allclose(np.asarray(d_var), (want * tangent).sum(1), rtol=1e-5,
                               atol=1e-6)


def test_variance_gradients_finite_where_cameras_missing():
    rng = np.random.default_rng(0)
    f = jnp.asarray(rng.normal(size=(1, 3, 2, 2, 2, 2)), jnp.float32)
    v = jnp.asarray(np.array([1, 0, 0])[None, :, None, None, None] * np.ones((1, 3, 2, 2, 2)))
    g = jax.grad(lambda x: jnp.sum(masked_variance(x, v)))(f)
    assert np.all(np.isfinite(np.asarray(g))) and np.all(np.asarray(g) == 0.0)


@pytest.fixture(scope="module")
def variance_cv():
    module = VarianceCostVolume(4, 6, nnx.Rngs(1))
    module.eval()  # deterministic normalisation: running statistics
    return module


def test_variance_cost_volume_order_masks_and_camera_count(variance_cv):
    rng = np.random.default_rng(2)
    f4 = jnp.asarray(rng.normal(size=(1, 4, 2, 3, 4, 4)), jnp.float32)
    v4 = jnp.asarray(rng.random((1, 4, 2, 3, 4)) < 0.8)
    out = np.asarray(variance_cv(f4, v4))
    assert out.shape == (1, 2, 3, 4, 6)
    perm = jnp.asarray([2, 0, 3, 1])
    np.testing.assert_allclose(np.asarray(variance_cv(f4[:, perm], v4[:, perm])), out,
                               rtol=1e-5, atol=1e-6)
    # A fifth camera that sees nothing (arbitrary features) changes nothing.
    f5 = jnp.concatenate([f4, jnp.asarray(rng.normal(size=(1, 1, 2, 3, 4, 4)), jnp.float32)], 1)
    v5 = jnp.concatenate([v4, jnp.zeros((1, 1, 2, 3, 4), bool)], 1)
    np.testing.assert_allclose(np.asarray(variance_cv(f5, v5)), out, rtol=1e-5, atol=1e-6)
    # Three cameras through the same weights: the fuse conv of the numpy variance.
    out3 = np.asarray(variance_cv(f4[:, :3], v4[:, :3]))
    ref3 = variance_cv.fuse(jnp.asarray(_np_variance(np.asarray(f4[:, :3]),
                                                     np.asarray(v4[:, :3])), jnp.float32))
    np.testing.assert_allclose(out3, np.asarray(ref3), rtol=1e-4, atol=1e-5)
    assert not np.allclose(out3, out)


def test_concat_cost_volume_stacks_camera_major_and_fixes_count():
    module = ConcatCostVolume(3, 2, 5, nnx.Rngs(3))
    module.eval()
    rng = np.random.default_rng(4)
    f = rng.normal(size=(1, 3, 2, 3, 4, 2)).astype(np.float32)
    v = np.ones((1, 3, 2, 3, 4))
    stacked = np.concatenate([f[:, k] for k in range(3)], axis=-1)
    np.testing.assert_allclose(np.asarray(module(jnp.asarray(f), jnp.asarray(v))),
                               np.asarray(module.fuse(jnp.asarray(stacked))), rtol=1e-5,
                               atol=1e-6)
    with pytest.raises(ValueError, match="4 cameras"):
        module(jnp.zeros((1, 4, 2, 3, 4, 2)), jnp.ones((1, 4, 2, 3, 4)))
    with pytest.raises(ValueError, match="valid"):
        module(jnp.zeros((1, 3, 2, 3, 4, 2)), jnp.ones((1, 3, 2, 3)))


# ----------------------------------------------------------------------------- upsampling, U-Net


def _np_upsample2(x: np.ndarray, axis: int) -> np.ndarray:
    """align_corners=False linear x2 from the general formula src = (o + 0.5) / 2 - 0.5."""
    n = x.shape[axis]
    src = np.clip((np.arange(2 * n) + 0.5) / 2 - 0.5, 0, n - 1)
    lo = np.floor(src).astype(int)
    hi = np.minimum(lo + 1, n - 1)
    t = src - lo
    shape = [1] * x.ndim
    shape[axis] = 2 * n
    t = t.reshape(shape)
    return np.take(x, lo, axis=axis) * (1 - t) + np.take(x, hi, axis=axis) * t


def test_upsample_matches_align_corners_false_reference():
    rng = np.random.default_rng(5)
    x = rng.normal(size=(2, 3, 4, 5, 2))
    ref = x
    for ax in (1, 2, 3):
        ref = _np_upsample2(ref, ax)
    np.testing.assert_allclose(np.asarray(upsample2(jnp.asarray(x), (1, 2, 3))), ref,
                               rtol=1e-5, atol=1e-6)
    # A length-1 axis just repeats.
    np.testing.assert_allclose(np.asarray(upsample2(jnp.ones((1, 1, 3)), (1,))),
                               np.ones((1, 2, 3)))


def _conv_ranks(layer, x) -> set[int]:
    """Ranks of the inputs of every convolution in ``layer(x)``'s program: 4 for 2-D, 5 for 3-D."""
    jaxpr = jax.make_jaxpr(lambda v: layer(v))(x)
    return {e.invars[0].aval.ndim for e in jaxpr.eqns if e.primitive.name == "conv_general_dilated"}


def test_conv3d_split_lowering_equals_native():
    rng = np.random.default_rng(6)
    x = jnp.asarray(rng.normal(size=(2, 4, 6, 8, 3)), jnp.float32)
    # 24 output channels: the split lowering pads its kernel to 32 and slices (layers.py).
    for out, stride in ((5, 1), (5, 2), (24, 1), (24, 2)):
        layers = {}
        for lowering in ("split", "native"):
            layers[lowering] = Conv3D(3, out, 3, stride, nnx.Rngs(stride), use_bias=True,
                                      lowering=lowering)
            layers[lowering].bias[...] = jnp.arange(float(out))
        kernel = layers["native"].kernel[...]
        np.testing.assert_array_equal(np.asarray(layers["split"].kernel[...]), np.asarray(kernel))
        split, native = (np.asarray(layers[m](x)) for m in ("split", "native"))
        ref = jax.lax.conv_general_dilated(x, kernel, (stride,) * 3, [(1, 1)] * 3,
                                           dimension_numbers=("NDHWC", "DHWIO", "NDHWC"))
        assert split.shape == (2, 4 // stride, 6 // stride, 8 // stride, out)
        np.testing.assert_allclose(native, np.asarray(ref) + np.arange(float(out)), rtol=1e-5,
                                   atol=1e-5)
        np.testing.assert_allclose(split, native, rtol=1e-5, atol=1e-5)
        grads = {m: nnx.grad(lambda layer: jnp.sum(jnp.sin(layer(x))))(layers[m])
                 for m in ("split", "native")}
        np.testing.assert_allclose(np.asarray(grads["split"]["kernel"][...]),
                                   np.asarray(grads["native"]["kernel"][...]), rtol=1e-4,
                                   atol=1e-4)
    assert _conv_ranks(layers["split"], x) == {4} and _conv_ranks(layers["native"], x) == {5}
    with pytest.raises(ValueError, match="lowering"):
        Conv3D(3, 5, 3, 1, nnx.Rngs(0), lowering="fast")


def _np_tap_sum(z: np.ndarray) -> np.ndarray:
    """numpy reference of layers.tap_sum_2d: tap t = (j, l) reads z at (h + j - p, w + l - p)."""
    k = int(round(z.shape[-1] ** 0.5))
    p = k // 2
    n, h, w, _ = z.shape
    y = np.zeros((n, h, w, 1))
    for t in range(k * k):
        j, m = divmod(t, k)
        for hh in range(h):
            for ww in range(w):
                a, b = hh + j - p, ww + m - p
                if 0 <= a < h and 0 <= b < w:
                    y[:, hh, ww, 0] += z[:, a, b, t]
    return y


@pytest.mark.parametrize("k", [3, 5])
def test_tap_sum_matches_numpy_and_its_derivative_is_its_adjoint(k):
    rng = np.random.default_rng(k)
    z = rng.normal(size=(2, 5, 7, k * k))
    y = rng.normal(size=(2, 5, 7, 1))
    np.testing.assert_allclose(np.asarray(tap_sum_2d(jnp.asarray(z, jnp.float32))),
                               _np_tap_sum(z), rtol=1e-5, atol=1e-5)
    # A linear map: forward mode equals the map itself, and the gradient of <tap_sum(z), y>
    # is the adjoint applied to y, checked entry by entry through <A e_i, y>.
    zj = jnp.asarray(z, jnp.float32)
    _, tangent = jax.jvp(tap_sum_2d, (zj,), (zj,))
    np.testing.assert_allclose(np.asarray(tangent), _np_tap_sum(z), rtol=1e-5, atol=1e-5)
    grad = np.asarray(jax.grad(lambda v: jnp.sum(tap_sum_2d(v) * y.astype(np.float32)))(zj))
    adjoint = np.zeros_like(z)
    for idx in np.ndindex(*z.shape[1:]):
        e = np.zeros((1,) + z.shape[1:])
        e[(0,) + idx] = 1.0
        col = _np_tap_sum(e)[0]
        adjoint[(slice(None),) + idx] = np.einsum("hwc,nhwc->n", col, y)
    np.testing.assert_allclose(grad, adjoint, rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match="k\\*k tap channels"):
        tap_sum_2d(jnp.zeros((1, 3, 3, 8)))


def test_one_output_conv3d_matches_native_in_value_gradients_and_forward_mode():
    """The split lowering's one-output-channel form (the U-Net head) against XLA's own 3-D
    conv: values, input and kernel gradients, and a forward-mode derivative."""
    rng = np.random.default_rng(8)
    x = jnp.asarray(rng.normal(size=(2, 4, 6, 8, 16)), jnp.float32)
    dx = jnp.asarray(rng.normal(size=x.shape), jnp.float32)
    layers = {m: Conv3D(16, 1, 3, 1, nnx.Rngs(3), use_bias=True, lowering=m)
              for m in ("split", "native")}
    for layer in layers.values():
        layer.bias[...] = jnp.asarray([0.25])
    kernel = layers["native"].kernel[...]
    ref = jax.lax.conv_general_dilated(x, kernel, (1, 1, 1), [(1, 1)] * 3,
                                       dimension_numbers=("NDHWC", "DHWIO", "NDHWC")) + 0.25
    np.testing.assert_allclose(np.asarray(layers["split"](x)), np.asarray(ref), rtol=1e-5,
                               atol=1e-5)

    def loss(layer, v):
        return jnp.sum(jnp.sin(layer(v)))

    grads = {m: nnx.grad(loss, argnums=(0, 1))(layers[m], x) for m in layers}
    np.testing.assert_allclose(np.asarray(grads["split"][0]["kernel"][...]),
                               np.asarray(grads["native"][0]["kernel"][...]), rtol=1e-4,
                               atol=1e-4)
    np.testing.assert_allclose(np.asarray(grads["split"][1]), np.asarray(grads["native"][1]),
                               rtol=1e-4, atol=1e-5)
    tangents = {m: jax.jvp(lambda v, layer=layers[m]: layer(v), (x,), (dx,))[1] for m in layers}
    np.testing.assert_allclose(np.asarray(tangents["split"]), np.asarray(tangents["native"]),
                               rtol=1e-5, atol=1e-5)
    # The head's form: its only 2-D convs are the one-hot tap sums (9 input channels), none
    # over stacked depth taps (48); below 16 input channels the stacked form stays.
    jaxpr = jax.make_jaxpr(lambda v: layers["split"](v))(x)
    assert {e.invars[0].aval.shape[-1] for e in jaxpr.eqns
            if e.primitive.name == "conv_general_dilated"} == {9}
    narrow = Conv3D(8, 1, 3, 1, nnx.Rngs(3), lowering="split")
    jaxpr = jax.make_jaxpr(lambda v: narrow(v))(x[..., :8])
    assert {e.invars[0].aval.shape[-1] for e in jaxpr.eqns
            if e.primitive.name == "conv_general_dilated"} == {24}


def test_conv3d_lowering_is_seen_by_jit():
    """The lowering is part of the module graph: one jitted function traces once per lowering,
    each trace with that lowering's convolutions."""
    x = jnp.asarray(np.random.default_rng(7).normal(size=(1, 2, 4, 4, 2)), jnp.float32)
    traced = []

    @nnx.jit
    def apply(layer, v):
        traced.append((layer.lowering, _conv_ranks(layer, v)))
        return layer(v)

    outs = {m: np.asarray(apply(Conv3D(2, 3, 3, 1, nnx.Rngs(0), lowering=m), x))
            for m in ("split", "native", "split")}
    assert traced == [("split", {4}), ("native", {5})]
    np.testing.assert_allclose(outs["split"], outs["native"], rtol=1e-5, atol=1e-5)


def test_kernel_init_is_truncated_lecun_normal_and_equal_under_jit():
    from scipy import stats

    shape = (3, 3, 3, 48, 96)  # fan_in 1296; 124 416 values: two chunks, the second cut
    fan_in = 3 * 3 * 3 * 48
    w = np.asarray(kernel_init(jax.random.key(3), shape))
    assert w.shape == shape and w.dtype == np.float32
    # LeCun normal: a unit normal truncated to [-2, 2], rescaled to std 1 / sqrt(fan_in).
    unit = stats.truncnorm(-2.0, 2.0)
    z = w.ravel() * math.sqrt(fan_in) * unit.std()
    assert abs(z.std() - unit.std()) < 0.01 and abs(z.mean()) < 0.01
    assert abs(w.std() * math.sqrt(fan_in) - 1.0) < 0.01
    assert np.abs(z).max() <= 2.0 + 1e-5 and np.abs(z).max() > 1.99
    assert stats.kstest(z, unit.cdf).pvalue > 1e-3
    # The chunks are independent draws, not copies of one another.
    chunk = 1 << 16
    assert abs(np.corrcoef(z[:chunk // 2], z[chunk:chunk + chunk // 2])[0, 1]) < 0.02
    other = np.asarray(kernel_init(jax.random.key(4), shape))
    assert abs(np.corrcoef(w.ravel(), other.ravel())[0, 1]) < 0.02
    # A module built under jit (or eval_shape) holds the same numbers as one built eagerly.
    jitted = jax.jit(kernel_init, static_argnums=1)(jax.random.key(3), shape)
    np.testing.assert_array_equal(np.asarray(jitted), w)


def test_unet_shapes_and_validation():
    unet = nnx.eval_shape(lambda: UNet3D(3, 4, nnx.Rngs(0)))
    out = nnx.eval_shape(lambda m, v: m(v), unet, jax.ShapeDtypeStruct((2, 8, 16, 24, 3),
                                                                       jnp.float32))
    assert out.shape == (2, 8, 16, 24)
    for bad, match in [((1, 12, 8, 16, 3), "divisible by 8"), ((1, 8, 12, 16, 3), "divisible by 8"),
                       ((1, 8, 8, 20, 3), "divisible by 8"), ((1, 8, 8, 16, 4), "UNet3D expects")]:
        with pytest.raises(ValueError, match=match):
            nnx.eval_shape(lambda m, v: m(v), unet, jax.ShapeDtypeStruct(bad, jnp.float32))


def test_feature_extractor_shapes_and_validation():
    for name in ("G16-cpu", "G16VV-cpu"):
        cfg = get_preset(name)
        fx = nnx.eval_shape(lambda c=cfg: FeatureExtractor(c, nnx.Rngs(0)))
        out = nnx.eval_shape(lambda m, x: m(x), fx,
                             jax.ShapeDtypeStruct((2, *cfg.surrogate_hw, 3), jnp.float32))
        assert out.shape == (2, 32, 128, 8)
    with pytest.raises(ValueError, match="divisible by 4"):
        nnx.eval_shape(lambda m, x: m(x), fx, jax.ShapeDtypeStruct((1, 130, 512, 3), jnp.float32))
    with pytest.raises(ValueError, match="SphericalConv built for 32 x 128"):
        nnx.eval_shape(lambda m, x: m(x), fx, jax.ShapeDtypeStruct((1, 64, 512, 3), jnp.float32))
    with pytest.raises(ValueError, match="3\\)"):
        nnx.eval_shape(lambda m, x: m(x), fx, jax.ShapeDtypeStruct((1, 128, 512, 1), jnp.float32))


# ----------------------------------------------------------------------------- regressor


def test_regress_matches_numpy_reference():
    rng = np.random.default_rng(8)
    logits = rng.normal(size=(2, 8, 3, 5)) * 3
    cand = np.geomspace(0.5, 100.0, 8)
    out = regress(jnp.asarray(logits, jnp.float32), jnp.asarray(cand, jnp.float32), (6, 10))
    up = _np_upsample2(_np_upsample2(logits, 2), 3)
    e = np.exp(up - up.max(1, keepdims=True))
    p = e / e.sum(1, keepdims=True)
    inv = (p / cand[None, :, None, None]).sum(1)
    ent = -(p * np.log(p)).sum(1)
    np.testing.assert_allclose(np.asarray(out["prob"]), p, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(np.asarray(out["inv_distance"]), inv, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(out["distance"]), 1 / inv, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(out["entropy"]), ent, rtol=1e-4, atol=1e-6)
    assert out["inv_distance"].shape == (2, 6, 10) and out["prob"].shape == (2, 8, 6, 10)
    # A confident one-hot pick returns that candidate; a flat one has entropy log D (same
    # shapes as above: no new compilation).
    hot = np.full((2, 8, 3, 5), -50.0)
    hot[:, 5] = 50.0
    hot[1] = 0.0
    r = regress(jnp.asarray(hot, jnp.float32), jnp.asarray(cand, jnp.float32), (6, 10))
    np.testing.assert_allclose(np.asarray(r["distance"][0]), cand[5], rtol=1e-5)
    np.testing.assert_allclose(np.asarray(r["entropy"][1]), math.log(8), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(r["inv_distance"][1]), np.mean(1 / cand), rtol=1e-5)
    with pytest.raises(ValueError, match="output_hw"):
        regress(jnp.zeros((1, 8, 3, 5)), jnp.asarray(cand), (4, 7))
    # Output at the logits' own size (output_stride 1): the softmax of the logits themselves.
    logits = np.random.default_rng(3).normal(size=(1, 8, 3, 5)).astype(np.float32)
    same = regress(jnp.asarray(logits), jnp.asarray(cand, jnp.float32), (3, 5))
    e = np.exp(logits - logits.max(axis=1, keepdims=True))
    np.testing.assert_allclose(np.asarray(same["prob"]), e / e.sum(axis=1, keepdims=True),
                               rtol=1e-5, atol=1e-7)
    with pytest.raises(ValueError, match="candidates"):
        regress(jnp.zeros((1, 8, 3, 5)), jnp.asarray(cand[:4]), (6, 10))


def _np_mode(prob, inv_cand, window, pick=0):
    """The sub-pixel mode by arg-max (an independent reference: the library builds the window
    from a maximum and shifts): per pixel, the expectation over the candidates within
    ``window`` places of the one with the most probability within ``pick`` places."""
    b, d, h, w = prob.shape
    out = np.empty((b, h, w))
    for i in range(b):
        for y in range(h):
            for x in range(w):
                p = prob[i, :, y, x]
                mass = [p[max(k - pick, 0):k + pick + 1].sum() for k in range(d)]
                a = int(np.argmax(mass))
                lo, hi = max(a - window, 0), min(a + window, d - 1) + 1
                out[i, y, x] = np.dot(p[lo:hi], inv_cand[lo:hi]) / p[lo:hi].sum()
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), window=st.integers(0, 9), scale=st.floats(0.5, 6.0),
       pick=st.integers(0, 3))
def test_mode_estimate_matches_an_argmax_reference(seed, window, scale, pick):
    """Random logits (ties have probability zero): the mode estimate, read at any pick,
    equals the arg-max reference, lies between the window's candidates, and a window as wide
    as the list gives the mean."""
    from gijax.nn.regressor import estimate_inverse

    rng = np.random.default_rng(seed)
    logits = rng.normal(size=(2, 8, 2, 3)) * scale
    prob = np.exp(logits - logits.max(1, keepdims=True))
    prob /= prob.sum(1, keepdims=True)
    inv_cand = 1.0 / np.geomspace(0.5, 100.0, 8)
    with jax.enable_x64(True):
        got = np.asarray(estimate_inverse(jnp.asarray(prob), jnp.asarray(inv_cand), "mode",
                                          window, pick))
        mean = np.asarray(estimate_inverse(jnp.asarray(prob), jnp.asarray(inv_cand), "mean"))
    np.testing.assert_allclose(got, _np_mode(prob, inv_cand, window, pick), rtol=1e-12)
    np.testing.assert_allclose(mean, np.einsum("bdhw,d->bhw", prob, inv_cand), rtol=1e-12)
    if window >= 7:
        np.testing.assert_allclose(got, mean, rtol=1e-12)
    if window == 0 and pick == 0:
        np.testing.assert_allclose(got, inv_cand[prob.argmax(1)], rtol=1e-12)


def test_the_mode_read_at_a_pick_takes_the_surface_with_the_most_probability():
    """A 32-candidate pixel seen on a trained network: a false match of 0.30 on candidate 14
    and the true surface between candidates 26 and 27 (0.24 + 0.29). Tulyakov's rule (pick 0)
    takes the false match; pick 1 (the most probability within one candidate on each side)
    takes the surface, and the model reads the pick its configuration names."""
    from gijax.nn.regressor import estimate_inverse

    inv_cand = np.linspace(2.0, 0.01, 32)
    p = np.full(32, 0.002)
    p[[13, 14, 15, 25, 26, 27, 28]] = [0.03, 0.30, 0.07, 0.03, 0.24, 0.29, 0.02]
    p /= p.sum()
    prob = jnp.asarray(p.reshape(1, 32, 1, 1), jnp.float32)
    inv = jnp.asarray(inv_cand, jnp.float32)
    peak = float(estimate_inverse(prob, inv, "mode", 2, 0)[0, 0, 0])
    surface = float(estimate_inverse(prob, inv, "mode", 2, 1)[0, 0, 0])
    assert inv_cand[15] < peak < inv_cand[13]
    assert inv_cand[28] < surface < inv_cand[25]
    assert surface == pytest.approx(np.dot(p[24:29], inv_cand[24:29]) / p[24:29].sum(),
                                    rel=1e-5)
    logits = jnp.log(prob)
    cand = 1.0 / inv
    assert float(regress(logits, cand, (1, 1), "mode", 2, 1)["inv_distance"][0, 0, 0]) == \
        pytest.approx(surface, rel=1e-5)
    with pytest.raises(ValueError, match="pick"):
        estimate_inverse(prob, inv, "mode", 2, -1)
    with pytest.raises(ValueError, match="mode_pick"):
        dataclasses.replace(get_preset("G16VV-cpu"), estimate="mode", mode_pick=-1)


def test_mode_estimate_takes_the_stronger_surface_at_an_edge():
    """Two surfaces in one pixel (0.55 of the mass around candidate 2, 0.45 around candidate
    12): the mean lands between them, the mode within a candidate of the stronger one; a tie
    widens the window over both neighbourhoods; the regressor reads the configured estimate
    and a gradient flows to the logits inside the window only."""
    from gijax.nn.regressor import estimate_inverse, mode_window_mask

    cand = np.geomspace(0.5, 100.0, 16)
    inv_cand = 1.0 / cand
    p = np.full(16, 1e-4)
    p[[1, 2, 3]] = [0.1, 0.35, 0.1]
    p[[11, 12, 13]] = [0.1, 0.25, 0.1]
    p /= p.sum()
    prob = p.reshape(1, 16, 1, 1)
    mean = float(np.dot(p, inv_cand))
    mode = float(estimate_inverse(jnp.asarray(prob, jnp.float32),
                                  jnp.asarray(inv_cand, jnp.float32), "mode", 2)[0, 0, 0])
    expected = np.dot(p[0:5], inv_cand[0:5]) / p[0:5].sum()
    assert mode == pytest.approx(expected, rel=1e-5)
    assert inv_cand[3] < mode < inv_cand[1]                   # on the near surface
    assert inv_cand[10] < mean < inv_cand[3]                  # between the two
    tie = np.zeros(16)
    tie[[4, 12]] = 0.5
    mask = np.asarray(mode_window_mask(jnp.asarray(tie.reshape(1, 16, 1, 1)), 1))[0, :, 0, 0]
    assert np.flatnonzero(mask).tolist() == [3, 4, 5, 11, 12, 13]
    logits = jnp.asarray(np.log(prob), jnp.float32)
    out = regress(logits, jnp.asarray(cand, jnp.float32), (1, 1), "mode", 2)
    assert float(out["inv_distance"][0, 0, 0]) == pytest.approx(expected, rel=1e-4)
    np.testing.assert_allclose(np.asarray(out["prob"])[:, :, 0, 0], prob[:, :, 0, 0],
                               rtol=1e-5)
    grad = np.asarray(jax.grad(lambda z: regress(z, jnp.asarray(cand, jnp.float32), (1, 1),
                                                   "mode", 2)["inv_distance"].sum())(logits))
    # The renormalised window does not depend on the logits outside it (up to rounding of the
    # softmax's shared normaliser).
    # Inside it, d mode / d z_i = p_i (q_i - mode) / sum_W p (softmax logits z).
    closed = p[0:5] * (inv_cand[0:5] - expected) / p[0:5].sum()
    np.testing.assert_allclose(grad[0, :5, 0, 0], closed, rtol=2e-3, atol=1e-8)
    assert np.abs(grad[0, 5:]).max() < 1e-6 * np.abs(grad[0, :5]).max()
    with pytest.raises(ValueError, match="estimate"):
        estimate_inverse(jnp.asarray(prob), jnp.asarray(inv_cand), "median")
    with pytest.raises(ValueError, match="mode_window"):
        dataclasses.replace(get_preset("G16VV-cpu"), estimate="mode", mode_window=-1)
    with pytest.raises(ValueError, match="estimate"):
        dataclasses.replace(get_preset("G16VV-cpu"), estimate="median")


# ----------------------------------------------------------------------------- spherical conv


def test_tangent_offsets_equator_and_pole_closed_forms():
    h, w = 64, 256  # 90 / 64 = 360 / 256 = 1.40625 deg per pixel
    off = tangent_offsets(h, w)
    assert off.shape == (h, 9, 2)
    grid = np.stack(np.meshgrid([-1, 0, 1], [-1, 0, 1], indexing="ij"), -1).reshape(9, 2)
    # Last row: latitude -0.7 deg, next to the equator: the plain grid up to O(pixel^2) terms.
    np.testing.assert_allclose(off[-1], grid, atol=2e-3)
    dlat, dlon = (math.pi / 2) / h, 2 * math.pi / w
    lat = -math.pi / 2 + (np.arange(h) + 0.5) * dlat
    # Side taps (i = 0, j = +-1): lon = atan(tan dlon / cos lat), lat' = asin(sin lat cos dlon).
    side_col = np.degrees(np.arctan(np.tan(dlon) / np.cos(lat))) / np.degrees(dlon)
    side_row = (np.arcsin(np.sin(lat) * np.cos(dlon)) - lat) / dlat
    np.testing.assert_allclose(off[:, 5, 1], side_col, rtol=1e-9)
    np.testing.assert_allclose(off[:, 3, 1], -side_col, rtol=1e-9)
    np.testing.assert_allclose(off[:, 5, 0], side_row, atol=1e-9)
    # Widening ~ 1 / cos(lat) where the kernel is still small next to the pole distance.
    rows = np.arange(8, 20)
    np.testing.assert_allclose(off[rows, 5, 1], 1 / np.cos(lat[rows]), rtol=0.03)
    assert off[3, 5, 1] > 5 and off[-1, 5, 1] < 1.001
    # Taps along the meridian stay one row away, except across the pole: the first row's
    # upward tap lands on the same ring half a turn around.
    np.testing.assert_allclose(off[1:, 1], np.array([[-1.0, 0.0]] * (h - 1)), atol=1e-9)
    np.testing.assert_allclose(off[:, 7], np.array([[1.0, 0.0]] * h), atol=1e-9)
    np.testing.assert_allclose(abs(off[0, 1, 1]), w / 2, atol=1e-9)
    np.testing.assert_allclose(off[0, 1, 0], 0.0, atol=1e-9)


def _integer_grid_case():
    """(x, 3x3 kernel, tap tables on the integer grid, the plain conv with wrapped columns, the
    first row repeated above and zeros below): the spherical conv's oracle."""
    rng = np.random.default_rng(9)
    h, w, c, co = 5, 12, 3, 4
    x = rng.normal(size=(2, h, w, c)).astype(np.float32)
    kernel = rng.normal(size=(3, 3, c, co)).astype(np.float32)
    grid = np.stack(np.meshgrid([-1, 0, 1], [-1, 0, 1], indexing="ij"), -1).reshape(9, 2)
    index, weight = sampling_tables(np.broadcast_to(grid, (h, 9, 2)).astype(float), w)
    padded = np.concatenate([x[:, :1], x, np.zeros_like(x[:, :1])], axis=1)
    padded = np.concatenate([padded[:, :, -1:], padded, padded[:, :, :1]], axis=2)
    ref = jax.lax.conv_general_dilated(jnp.asarray(padded), jnp.asarray(kernel), (1, 1),
                                       "VALID", dimension_numbers=("NHWC", "HWIO", "NHWC"))
    return x, kernel, index, weight, np.asarray(ref)


def test_spherical_gather_equals_plain_conv_on_an_integer_grid():
    """With integer grid offsets the tap gather + (9 C) -> C_out mix is exactly a 3x3 conv with
    wrapped columns, the first row repeated above and zeros below."""
    x, kernel, index, weight, ref = _integer_grid_case()
    taps = gather_taps(jnp.asarray(x), jnp.asarray(index), jnp.asarray(weight))
    got = np.asarray(taps.reshape(*x.shape[:3], -1) @ kernel.reshape(-1, kernel.shape[-1]))
    np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-4)


def test_spherical_conv_mixes_tap_by_tap_at_inference():
    """Eval mode mixes the taps one at a time (no (B, H, W, 9, C) stack): on an integer grid
    that is the plain 3x3 conv too, and the module's eval output equals its stacked form."""
    from flax import nnx

    from gijax.nn.layers import leaky_relu
    from gijax.nn.spherical import SphericalConv, _cached_tables, mix_taps_one_by_one

    x, kernel, index, weight, ref = _integer_grid_case()
    h, w, c, co = *x.shape[1:], kernel.shape[-1]
    rng = np.random.default_rng(10)
    got = np.asarray(mix_taps_one_by_one(jnp.asarray(x), jnp.asarray(index),
                                         jnp.asarray(weight), kernel.reshape(9 * c, co)))
    np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-4)

    conv = SphericalConv(c, co, h, w, nnx.Rngs(0), taps="release")
    conv.bn.mean[...] = jnp.asarray(rng.normal(size=co), jnp.float32)
    conv.bn.var[...] = jnp.asarray(rng.uniform(0.5, 2.0, size=co), jnp.float32)
    conv.eval()
    idx, wgt = _cached_tables("release", h, w, -math.pi / 2, 0.0)
    taps = gather_taps(jnp.asarray(x), jnp.asarray(idx), jnp.asarray(wgt))
    stacked = leaky_relu(conv.bn(conv.mix(taps.reshape(2, h, w, 9 * c))))
    np.testing.assert_allclose(np.asarray(conv(jnp.asarray(x))), np.asarray(stacked),
                               rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("taps", ["release", "tangent"])
def test_spherical_training_backward_is_the_gathers_transpose(taps):
    """Training mode's gather has a hand-written backward (a gather through
    ``transposed_tables``). Oracles: the dense sampling matrix built from the tables with
    ``np.add.at`` (its transpose), and autodiff of the plain :func:`gather_taps`."""
    from gijax.nn.spherical import _cached_tables, _fixed_tap_gather, transposed_tables

    h, w, c = 5, 12, 3
    index, weight = _cached_tables(taps, h, w, -math.pi / 2, 0.0)
    t_index, t_weight = transposed_tables(index, weight, h * w)
    positions = index.shape[1] * index.shape[2] * index.shape[3]
    dense = np.zeros((positions, h * w))
    full = np.broadcast_to(weight, index.shape).reshape(4, -1)
    np.add.at(dense, (np.arange(positions)[None].repeat(4, 0), index.reshape(4, -1)), full)
    back = np.zeros((h * w, positions))
    np.add.at(back, (np.arange(h * w)[:, None].repeat(t_index.shape[1], 1), t_index), t_weight)
    np.testing.assert_allclose(back, dense.T, atol=1e-7)

    rng = np.random.default_rng(11)
    x = jnp.asarray(rng.normal(size=(2, h, w, c)), jnp.float32)
    ct = jnp.asarray(rng.normal(size=(2, h, w, 9, c)), jnp.float32)
    gather = _fixed_tap_gather(taps, h, w, -math.pi / 2, 0.0)
    out, vjp = jax.vjp(gather, x)
    ref_out, ref_vjp = jax.vjp(
        lambda v: gather_taps(v, jnp.asarray(index), jnp.asarray(weight)), x)
    np.testing.assert_allclose(np.asarray(out), np.asarray(ref_out), rtol=0, atol=0)
    np.testing.assert_allclose(np.asarray(vjp(ct)[0]), np.asarray(ref_vjp(ct)[0]),
                               rtol=1e-5, atol=1e-5)
    expected = (dense.T @ np.asarray(ct, np.float64).reshape(2, positions, c))
    np.testing.assert_allclose(np.asarray(jax.jit(lambda g: vjp(g)[0])(ct)),
                               expected.reshape(2, h, w, c), rtol=1e-5, atol=1e-5)


def _np_zero_padded_bilinear(img, row, col):
    """Reference bilinear sample of (H, W, C) at one (row, col), neighbours outside = 0."""
    h, w = img.shape[:2]
    r0, c0 = math.floor(row), math.floor(col)
    out = np.zeros(img.shape[-1])
    for r, c, wgt in ((r0, c0, (1 - (row - r0)) * (1 - (col - c0))),
                      (r0, c0 + 1, (1 - (row - r0)) * (col - c0)),
                      (r0 + 1, c0, (row - r0) * (1 - (col - c0))),
                      (r0 + 1, c0 + 1, (row - r0) * (col - c0))):
        if 0 <= r < h and 0 <= c < w:
            out += wgt * img[r, c]
    return out


def test_release_taps_sample_where_deform_conv_does():
    """The 'release' taps: tap (i, j) of pixel (y, x) reads (y - 1 + i + dy, x - 1 + j + dx)
    with the release's offsets, bilinear with zero padding (torchvision deform_conv2d)."""
    from gijax.nn.spherical import _cached_tables, release_offsets

    rng = np.random.default_rng(4)
    h, w, c = 6, 16, 2
    x = rng.normal(size=(1, h, w, c)).astype(np.float32)
    index, weight = _cached_tables("release", h, w, -math.pi / 2, 0.0)
    got = np.asarray(gather_taps(jnp.asarray(x), jnp.asarray(index), jnp.asarray(weight)))[0]
    off = release_offsets(h, w)
    for y, xx in [(0, 0), (2, 7), (5, 15), (3, 0)]:
        for k in range(9):
            i, j = divmod(k, 3)
            ref = _np_zero_padded_bilinear(x[0], y - 1 + i + off[y, xx, k, 0],
                                           xx - 1 + j + off[y, xx, k, 1])
            np.testing.assert_allclose(got[y, xx, k], ref, atol=1e-5)
    # Not the tangent kernel: at mid latitudes the side taps land about twice as far out.
    tangent = tangent_offsets(h, w)
    mid = h // 2
    release_side = -1 + 2 + off[mid, w // 2, 5, 1]
    ratio = release_side / tangent[mid, 5, 1]
    assert ratio > 1.6 and ratio < 2.6, ratio


def test_spherical_taps_are_a_config_choice():
    cfg = dataclasses.replace(get_preset("G16VV-cpu"), surrogate_hw=(32, 128), cost_hw=(8, 16),
                              output_hw=(16, 32))
    x = jnp.asarray(np.random.default_rng(0).normal(size=(1, 32, 128, 3)), jnp.float32)
    outs = {}
    for taps in ("release", "tangent"):
        model = FeatureExtractor(dataclasses.replace(cfg, spherical_taps=taps), nnx.Rngs(0))
        model.eval()
        outs[taps] = np.asarray(model(x))
    assert np.abs(outs["release"] - outs["tangent"]).max() > 1e-3
    with pytest.raises(ValueError, match="spherical_taps"):
        dataclasses.replace(cfg, spherical_taps="gnomonic")
    with pytest.raises(ValueError, match="sweep_boundary"):
        dataclasses.replace(cfg, sweep_boundary="clamp")


# ----------------------------------------------------------------------------- whole parts


def _small(name: str) -> ModelConfig:
    """A CPU preset shrunk further in space only (same layers and channels)."""
    return dataclasses.replace(get_preset(name), surrogate_hw=(32, 128), cost_hw=(8, 16),
                               output_hw=(16, 32))


def _pipeline(model: OmniStereoNet, images, coords, valid, cand):
    """The network's stages, with a stand-in sweep (bilinear sampling at fixed coordinates):
    features -> sweep -> cost volume -> U-Net -> regression."""
    b = images.shape[0]
    feats = model.extract_features(images)
    sample = jax.vmap(jax.vmap(lambda im, c, v: bilinear_sample(im, c, v)[0],
                               in_axes=(0, 0, 0)), in_axes=(0, None, None))
    swept = sample(feats, coords, valid)
    vol = model.build_cost_volume(swept, jnp.broadcast_to(valid, (b, *valid.shape)))
    return model.regress(model.unet_logits(vol), cand)


def _inputs(cfg: ModelConfig, b: int = 2):
    rng = np.random.default_rng(10)
    n, d = cfg.num_cameras, cfg.num_candidates
    hf, wf = cfg.feature_hw
    images = jnp.asarray(rng.random((b, n, *cfg.surrogate_hw, 3)), jnp.float32)
    coords = rng.random((n, d, *cfg.cost_hw, 2)) * np.array([wf - 1, hf - 1])
    valid = rng.random((n, d, *cfg.cost_hw)) < 0.9
    cand = jnp.asarray(np.geomspace(0.5, 100.0, d), jnp.float32)
    return images, jnp.asarray(coords, jnp.float32), jnp.asarray(valid), cand


def test_spherical_cpu_parts_jit_equals_eager_and_all_gradients_finite_nonzero():
    """G16VV-cpu layers (spherical features, variance cost, U-Net) on a smaller grid: the eager
    feature extractor equals the jitted one, and a loss on the regressed output sends a finite,
    non-zero gradient to every parameter."""
    # Native 3-D convs: the same numbers as the CPU's split lowering, faster to compile.
    cfg = dataclasses.replace(_small("G16VV-cpu"), conv3d="native")
    model = OmniStereoNet(cfg, nnx.Rngs(11))
    model.train()
    images, coords, valid, cand = _inputs(cfg)
    target = jnp.asarray(np.random.default_rng(12).uniform(0.05, 1.5, (2, *cfg.output_hw)),
                         jnp.float32)
    flat = images.reshape(-1, *cfg.surrogate_hw, 3)
    eager_features = np.asarray(model.features(flat))

    graphdef, state = nnx.split(model)

    def loss_fn(model, imgs):
        out = _pipeline(model, imgs, coords, valid, cand)
        loss = jnp.mean((out["inv_distance"] - target) ** 2) + 1e-3 * jnp.mean(out["entropy"])
        return loss, (model.features(imgs.reshape(flat.shape)), out)

    def step(state, imgs):
        model = nnx.merge(graphdef, state)
        return nnx.value_and_grad(loss_fn, has_aux=True)(model, imgs)

    # No LLVM optimisation: the same numbers, a third of the compile time.
    (loss, (jit_features, out)), grads = jax.jit(
        step, compiler_options={"xla_backend_optimization_level": 0})(state, images)
    params = nnx.state(model, nnx.Param)
    assert eager_features.shape == (6, *cfg.feature_hw, cfg.feature_channels)
    np.testing.assert_allclose(np.asarray(jit_features), eager_features, rtol=1e-4, atol=1e-5)
    assert np.isfinite(float(loss)) and np.all(np.isfinite(np.asarray(out["distance"])))
    leaves = jax.tree_util.tree_leaves_with_path(grads)
    assert len(leaves) == len(jax.tree_util.tree_leaves(params)) > 50
    for path, g in leaves:
        g = np.asarray(g)
        name = jax.tree_util.keystr(path)
        assert np.all(np.isfinite(g)), name
        assert np.any(g != 0), name
