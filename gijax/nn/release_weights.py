"""The authors' released PyTorch state dicts, mapped onto gijax's modules (pure, numpy only).

Names: the release's ``dsta_mvs`` model holds ``feature_extractor`` (``first``, ``blks``: the
residual blocks of both stages with the stride-2 conv between them, ``final_layer``),
``cv_builder.post_vol``, ``cv_regulator`` (``down_blks``, ``upBlks``, ``out_costs``) and
``dist_regressor.inv_dist_idx``. Layouts: PyTorch convs are (O, I, kh, kw[, kd]) and become
flax's (kh, kw[, kd], I, O) kernels; BatchNorm ``weight`` / ``bias`` / ``running_mean`` /
``running_var`` become ``scale`` / ``bias`` / ``mean`` / ``var`` (``num_batches_tracked`` has no
counterpart and is dropped); the spherical conv's (O, I, 3, 3) weight becomes the (9 I, O)
tap-major mixing matrix of :class:`gijax.nn.spherical.SphericalConv`, and its stored ``offset``
buffer is checked against :func:`gijax.nn.spherical.release_offsets` (released G16VV weights
need ``spherical_taps='release'``).

Colour order: the release feeds BGR images (OpenCV). With ``input_order='bgr'`` the first
conv's input channels are reversed on import, which is exact (a conv is linear in its input
channels), so the imported model takes RGB like every gijax model.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from gijax.nn.presets import ModelConfig
from gijax.nn.spherical import release_offsets

# Units of the release's inverse distance: bf / d with a dummy baseline x focal length of 96.
RELEASE_BF = 96.0

_BN = {"weight": "scale", "bias": "bias", "running_mean": "mean", "running_var": "var"}


def _conv_kernel(w: np.ndarray) -> np.ndarray:
    """(O, I, k...) -> (k..., I, O)."""
    return np.transpose(w, tuple(range(2, w.ndim)) + (1, 0))


def _feature_names(config: ModelConfig) -> dict[str, tuple]:
    """Release prefix -> gijax path prefix for the feature extractor's conv + BN blocks."""
    n1, n2 = config.feature_blocks
    names = {"feature_extractor.first": ("features", "stem")}
    for k in range(n1 + 1 + n2):
        src = f"feature_extractor.blks.{k}"
        if k < n1:
            dst = ("features", "blocks1", k)
        elif k == n1:
            names[src] = ("features", "down")
            continue
        else:
            dst = ("features", "blocks2", k - n1 - 1)
        names[src + ".blk1"] = dst + ("first",)
        names[src + ".blk2"] = dst + ("second",)
    if config.features == "plain":
        names["feature_extractor.final_layer"] = ("features", "last")
    return names


def _unet_names() -> dict[str, tuple]:
    names = {"cv_builder.post_vol": ("cost_volume", "fuse")}
    for s in range(3):
        src, dst = f"cv_regulator.down_blks.{s}", ("unet", f"down{s + 1}")
        names[src + ".first"] = dst + ("down",)
        for k in range(3):
            names[f"{src}.blks.{k}.blk1"] = dst + ("blocks", k, "first")
            names[f"{src}.blks.{k}.blk2"] = dst + ("blocks", k, "second")
    names["cv_regulator.upBlks.0.conv"] = ("unet", "up3", "conv")
    names["cv_regulator.upBlks.1.conv"] = ("unet", "up2", "conv")
    names["cv_regulator.out_costs.0.conv"] = ("unet", "up1", "conv")
    return names


def convert_state_dict(state_dict: Mapping[str, np.ndarray], config: ModelConfig,
                       input_order: str = "bgr") -> tuple[dict[tuple, np.ndarray], np.ndarray]:
    """A release state dict -> (gijax variables keyed by path tuple, candidates in metres).

    ``state_dict`` maps the release's names to arrays (a leading ``model.`` or ``module.``, as
    Lightning and DataParallel write them, is stripped). ``input_order`` is the colour order
    the released weights expect (``'bgr'`` for the release, ``'rgb'`` to keep them as they are).

    Raises ValueError listing every name it cannot map, every missing entry, and every shape
    that does not fit ``config``.
    """
    if input_order not in ("bgr", "rgb"):
        raise ValueError(f"input_order must be 'bgr' or 'rgb'; found {input_order!r}")
    sd = {}
    for name, value in state_dict.items():
        for prefix in ("model.", "module."):
            if name.startswith(prefix):
                name = name[len(prefix):]
        sd[name] = np.asarray(value)

    blocks = {**_feature_names(config), **_unet_names()}
    out: dict[tuple, np.ndarray] = {}
    used: set[str] = set()
    missing: list[str] = []

    def take(name: str):
        if name not in sd:
            missing.append(name)
            return None
        used.add(name)
        return sd[name]

    for src, dst in blocks.items():
        w = take(f"{src}.conv_layer.weight")
        if w is not None:
            out[dst + ("conv", "kernel")] = _conv_kernel(w)
        for torch_name, flax_name in _BN.items():
            v = take(f"{src}.norm_layer.{torch_name}")
            if v is not None:
                out[dst + ("bn", flax_name)] = v
        used.add(f"{src}.norm_layer.num_batches_tracked")
    head = "cv_regulator.out_costs.1.conv_layer"
    w, b = take(head + ".weight"), take(head + ".bias")
    if w is not None:
        out[("unet", "head", "kernel")] = _conv_kernel(w)
    if b is not None:
        out[("unet", "head", "bias")] = b
    if config.features == "spherical":
        src = "feature_extractor.final_layer.blk"
        w = take(src + ".0.weight")
        if w is not None:
            o, i = w.shape[:2]
            out[("features", "last", "mix", "kernel")] = (
                np.transpose(w, (2, 3, 1, 0)).reshape(9 * i, o))
        offset = take(src + ".0.offset")
        if offset is not None:
            _check_offsets(offset, config)
        for torch_name, flax_name in _BN.items():
            v = take(f"{src}.1.{torch_name}")
            if v is not None:
                out[("features", "last", "bn", flax_name)] = v
        used.add(src + ".1.num_batches_tracked")
    inv = take("dist_regressor.inv_dist_idx")
    candidates = None if inv is None else RELEASE_BF / np.asarray(inv, np.float64).reshape(-1)

    unknown = sorted(k for k in sd if k not in used)
    problems = []
    if missing:
        problems.append(f"missing entries: {', '.join(missing)}")
    if unknown:
        problems.append(f"names that do not map onto model {config.name!r}: "
                        f"{', '.join(unknown)}")
    if problems:
        raise ValueError("the state dict does not fit model "
                         f"{config.name!r} ({config.features} features, {config.cost_volume} "
                         f"cost volume, blocks {config.feature_blocks}); " + "; ".join(problems))
    if input_order == "bgr":
        key = ("features", "stem", "conv", "kernel")
        out[key] = out[key][:, :, ::-1, :].copy()
    return out, candidates


def _check_offsets(offset: np.ndarray, config: ModelConfig) -> None:
    h, w = config.feature_hw
    if offset.shape != (1, 18, h, w):
        raise ValueError(f"feature_extractor.final_layer.blk.0.offset has shape {offset.shape}; "
                         f"model {config.name!r} expects (1, 18, {h}, {w})")
    if config.spherical_taps != "release":
        raise ValueError(f"released spherical weights were trained with the release's taps; "
                         f"model {config.name!r} has spherical_taps="
                         f"{config.spherical_taps!r} (use 'release')")
    mine = release_offsets(h, w).transpose(2, 3, 0, 1).reshape(1, 18, h, w)
    err = float(np.max(np.abs(mine - offset)))
    if err > 1e-3:
        raise ValueError(f"feature_extractor.final_layer.blk.0.offset differs from the release's "
                         f"offsets for a {h} x {w} map by up to {err:.3g} px")


def check_shapes(converted: Mapping[tuple, np.ndarray],
                 expected: Mapping[tuple, tuple[int, ...]], name: str) -> None:
    """ValueError listing every converted entry whose shape differs from the model's, and every
    model variable the conversion did not provide."""
    bad = [f"{'/'.join(map(str, k))}: found {tuple(v.shape)}, expected {tuple(expected[k])}"
           for k, v in converted.items() if k in expected and tuple(v.shape) != tuple(expected[k])]
    extra = ['/'.join(map(str, k)) for k in converted if k not in expected]
    absent = ['/'.join(map(str, k)) for k in expected if k not in converted]
    problems = []
    if bad:
        problems.append("shape mismatches: " + "; ".join(bad))
    if absent:
        problems.append("model variables not in the state dict: " + ", ".join(absent))
    if extra:
        problems.append("converted entries the model does not have: " + ", ".join(extra))
    if problems:
        raise ValueError(f"released weights do not fit model {name!r}: " + "; ".join(problems))


def load_state_dict(model, state_dict: Mapping[str, np.ndarray],
                    input_order: str = "bgr") -> np.ndarray | None:
    """Write a release state dict into ``model`` (an :class:`gijax.model.OmniStereoNet`) in
    place, put it in eval mode, and return the candidates stored in the state dict (metres;
    None when it holds none). ValueError as :func:`convert_state_dict` and
    :func:`check_shapes`."""
    import jax.numpy as jnp
    from flax import nnx, traverse_util

    config = model.config
    converted, candidates = convert_state_dict(state_dict, config, input_order)
    state = nnx.state(model)
    flat = traverse_util.flatten_dict(nnx.to_pure_dict(state))
    check_shapes(converted, {k: tuple(v.shape) for k, v in flat.items()}, config.name)
    pure = traverse_util.unflatten_dict(
        {k: jnp.asarray(converted[k], v.dtype) for k, v in flat.items()})
    nnx.replace_by_pure_dict(state, pure)
    nnx.update(model, state)
    model.eval()
    return candidates
