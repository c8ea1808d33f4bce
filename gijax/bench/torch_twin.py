"""A PyTorch twin of gijax's network, the peer the ``torch-peer`` benchmark times gijax against.

The released architecture (REFERENCE section 4) written once more with ``torch.nn``, under the
release's module names, so that ``state_dict()`` carries the names of the authors' checkpoints:
:func:`gijax.nn.release_weights.load_state_dict` puts the twin's weights into a gijax model
unchanged (with ``input_order='rgb'``), and a released state dict loads into the twin as it is.
Like the release it takes the sweep grids precomputed, as its data loader makes them:
normalised ``grid_sample`` coordinates (``align_corners=False``) over the feature map, exported
from gijax's own sweep by the benchmark (:mod:`gijax.bench.torch_peer`).

Layouts are PyTorch's, channels first: surrogates (B, N, 3, Hs, Ws), masks (B, N, Hm, Wm),
features (B, N, C, hf, wf), cost volume (B, C, D, h, w), logits (B, D, h, w), probabilities
(B, D, H, W), inverse distance (B, H, W) in 1/m (the release's ``96 / d`` divided by 96).

The spherical feature layer is torchvision's ``deform_conv2d`` with the release's fixed offsets
when torchvision is installed; otherwise a bilinear stand-in samples the same taps with
``grid_sample`` (zero padding) and mixes them with one contraction (:data:`SPHERICAL_BACKEND`
says which). Only the release's choices are built: ``spherical_taps='release'``,
``sweep_boundary='zeros'``, no guided refinement.

This module imports torch, numpy and :mod:`gijax.bench.torch_peer` only (not JAX): the
benchmark runs it in a process of its own whose memory is the twin's alone. Nothing else in
gijax imports it.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from gijax.bench.torch_peer import twin_config

try:
    from torchvision.ops import deform_conv2d
except ImportError:  # the bilinear stand-in below samples the same taps
    deform_conv2d = None

SPHERICAL_BACKEND = ("torchvision.ops.deform_conv2d" if deform_conv2d is not None
                     else "grid_sample stand-in (torchvision not installed)")

# The release's constants, as gijax holds them (gijax.nn.layers, gijax.nn.release_weights,
# gijax.train.losses); repeated here because this module must not import JAX
# (tests/test_torch_twin.py checks that they agree).
LEAKY_SLOPE = 0.01
RELEASE_BF = 96.0
PROB_FLOOR = 1e-30


class ConvBN(nn.Module):
    """conv (no bias, padding k // 2) -> BatchNorm -> optional LeakyReLU, 2-D or 3-D, under
    the release's names ``conv_layer`` / ``norm_layer``."""

    def __init__(self, in_ch: int, out_ch: int, kernel: int, ndim: int, stride: int = 1,
                 activate: bool = True):
        super().__init__()
        conv = nn.Conv2d if ndim == 2 else nn.Conv3d
        norm = nn.BatchNorm2d if ndim == 2 else nn.BatchNorm3d
        self.conv_layer = conv(in_ch, out_ch, kernel, stride, kernel // 2, bias=False)
        self.norm_layer = norm(out_ch)
        self.activate = activate

    def forward(self, x):
        y = self.norm_layer(self.conv_layer(x))
        return F.leaky_relu(y, LEAKY_SLOPE) if self.activate else y


class Residual(nn.Module):
    """x + BN(conv3(LeakyReLU(BN(conv3(x))))) followed by LeakyReLU (``blk1``, ``blk2``)."""

    def __init__(self, channels: int, ndim: int):
        super().__init__()
        self.blk1 = ConvBN(channels, channels, 3, ndim)
        self.blk2 = ConvBN(channels, channels, 3, ndim, activate=False)

    def forward(self, x):
        return F.leaky_relu(x + self.blk2(self.blk1(x)), LEAKY_SLOPE)


class FixedOffsetConv(nn.Module):
    """3x3 deformable conv (stride 1, padding 1, no bias) with fixed offsets, the release's
    spherical layer: ``weight`` (O, I, 3, 3) and the ``offset`` buffer (1, 18, H, W), per tap
    (row-major) the (dy, dx) added to the kernel grid."""

    def __init__(self, in_ch: int, out_ch: int, offsets: np.ndarray):
        super().__init__()
        height, width = offsets.shape[:2]
        self.weight = nn.Parameter(torch.empty(out_ch, in_ch, 3, 3))
        nn.init.kaiming_uniform_(self.weight, a=5 ** 0.5)   # nn.Conv2d's default
        buf = np.asarray(offsets, np.float32).reshape(height, width, 18).transpose(2, 0, 1)
        self.register_buffer("offset", torch.from_numpy(np.ascontiguousarray(buf))[None])

    def forward(self, x):
        b = x.shape[0]
        if deform_conv2d is not None:
            return deform_conv2d(x, self.offset.expand(b, -1, -1, -1), self.weight, padding=1)
        return self._stand_in(x)

    def _stand_in(self, x):
        # Tap (i, j) of output pixel (y, x) samples (y - 1 + i + dy, x - 1 + j + dx), bilinear,
        # zero outside the map: grid_sample with align_corners=False at (2 p + 1) / size - 1.
        b, c, h, w = x.shape
        off = self.offset[0].reshape(9, 2, h, w)
        i = torch.arange(3, dtype=x.dtype, device=x.device).repeat_interleave(3)
        j = torch.arange(3, dtype=x.dtype, device=x.device).repeat(3)
        rows = (torch.arange(h, dtype=x.dtype, device=x.device)[None, :, None] - 1
                + i[:, None, None] + off[:, 0])                       # (9, H, W)
        cols = (torch.arange(w, dtype=x.dtype, device=x.device)[None, None, :] - 1
                + j[:, None, None] + off[:, 1])
        grid = torch.stack([(2 * cols + 1) / w - 1, (2 * rows + 1) / h - 1], -1)
        grid = grid.permute(1, 0, 2, 3).reshape(1, h, 9 * w, 2).expand(b, -1, -1, -1)
        taps = F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros",
                             align_corners=False).reshape(b, c, h, 9, w)
        return torch.einsum("bchkw,ock->bohw", taps, self.weight.reshape(-1, c, 9))


class SphericalLayer(nn.Module):
    """The release's ``final_layer`` of G16VV: ``blk`` = (fixed-offset conv, BN, LeakyReLU)."""

    def __init__(self, channels: int, offsets: np.ndarray):
        super().__init__()
        self.blk = nn.Sequential(FixedOffsetConv(channels, channels, offsets),
                                 nn.BatchNorm2d(channels), nn.LeakyReLU(LEAKY_SLOPE))

    def forward(self, x):
        return self.blk(x)


class FeatureExtractor(nn.Module):
    """5x5/2 conv, ``n1`` residual blocks, 3x3/2 conv, ``n2`` residual blocks (all in
    ``blks``), then the 3x3 conv (``final_layer``) or the spherical layer."""

    def __init__(self, cfg: dict, offsets: np.ndarray | None):
        super().__init__()
        c = cfg["feature_channels"]
        n1, n2 = cfg["feature_blocks"]
        self.first = ConvBN(3, c, 5, 2, stride=2)
        self.blks = nn.Sequential(*[Residual(c, 2) for _ in range(n1)],
                                  ConvBN(c, c, 3, 2, stride=2),
                                  *[Residual(c, 2) for _ in range(n2)])
        if cfg["features"] == "spherical":
            if offsets is None:
                raise ValueError(f"model {cfg['name']!r} has spherical features: give the "
                                 f"(H, W, 9, 2) tap offsets (gijax.nn.spherical.release_offsets)")
            self.final_layer = SphericalLayer(c, offsets)
        else:
            self.final_layer = ConvBN(c, c, 3, 2)

    def forward(self, x):
        return self.final_layer(self.blks(self.first(x)))


class CostVolumeBuilder(nn.Module):
    """Concat or masked variance of the swept features, then ``post_vol`` (3x3x3 conv + BN +
    LeakyReLU)."""

    def __init__(self, cfg: dict):
        super().__init__()
        self.kind = cfg["cost_volume"]
        in_ch = (cfg["num_cameras"] * cfg["feature_channels"] if self.kind == "concat"
                 else cfg["feature_channels"])
        self.post_vol = ConvBN(in_ch, cfg["unet_in"], 3, 3)

    def forward(self, swept, valid):
        """swept (B, N, C, D, h, w), valid (B, N, D, h, w) float -> (B, C_out, D, h, w)."""
        if self.kind == "concat":
            b, n, c = swept.shape[:3]
            return self.post_vol(swept.reshape(b, n * c, *swept.shape[3:]))
        return self.post_vol(masked_variance(swept, valid))


def masked_variance(swept, valid):
    """(B, N, C, D, h, w), (B, N, D, h, w) -> (B, C, D, h, w): ``sum_v (f - mean)^2 / count``
    over the valid cameras, 0 where fewer than 2 are valid."""
    v = valid[:, :, None]
    count = v.sum(1)
    safe = count.clamp(min=1.0)
    mean = (swept * v).sum(1) / safe
    var = ((swept - mean[:, None]) ** 2 * v).sum(1) / safe
    return torch.where(count >= 2.0, var, torch.zeros_like(var))


class DownStage(nn.Module):
    def __init__(self, in_ch: int, out_ch: int):
        super().__init__()
        self.first = ConvBN(in_ch, out_ch, 3, 3, stride=2)
        self.blks = nn.Sequential(*[Residual(out_ch, 3) for _ in range(3)])

    def forward(self, x):
        return self.blks(self.first(x))


class UpStage(nn.Module):
    """Trilinear x2 upsample, 3x3x3 conv + BN (``conv``); the caller adds the skip."""

    def __init__(self, in_ch: int, out_ch: int):
        super().__init__()
        self.conv = ConvBN(in_ch, out_ch, 3, 3, activate=False)

    def forward(self, x):
        return self.conv(F.interpolate(x, scale_factor=2, mode="trilinear",
                                       align_corners=False))


class Head(nn.Module):
    """The last 3x3x3 conv, in -> 1 with bias, no norm (``conv_layer``)."""

    def __init__(self, in_ch: int):
        super().__init__()
        self.conv_layer = nn.Conv3d(in_ch, 1, 3, 1, 1, bias=True)

    def forward(self, x):
        return self.conv_layer(x)


class UNet(nn.Module):
    """3 down stages (f, 2f, 4f), 2 up stages with skips, the last up stage and the head in
    ``out_costs``: (B, in, D, h, w) -> (B, D, h, w) logits."""

    def __init__(self, in_ch: int, base: int):
        super().__init__()
        self.down_blks = nn.ModuleList([DownStage(in_ch, base), DownStage(base, 2 * base),
                                        DownStage(2 * base, 4 * base)])
        self.upBlks = nn.ModuleList([UpStage(4 * base, 2 * base), UpStage(2 * base, base)])
        # The last up stage (no skip) and the head: the release's out_costs.0 and .1.
        self.out_costs = nn.ModuleList([UpStage(base, in_ch), Head(in_ch)])

    def forward(self, volume):
        s1 = self.down_blks[0](volume)
        s2 = self.down_blks[1](s1)
        s3 = self.down_blks[2](s2)
        x = F.leaky_relu(self.upBlks[0](s3) + s2, LEAKY_SLOPE)
        x = F.leaky_relu(self.upBlks[1](x) + s1, LEAKY_SLOPE)
        x = F.leaky_relu(self.out_costs[0](x), LEAKY_SLOPE)
        return self.out_costs[1](x)[:, 0]


class DistanceRegressor(nn.Module):
    """Logits upsampled x2 (bilinear, ``align_corners=False``; not at output stride 1), softmax
    over the candidates, expectation of the inverse distance. ``inv_dist_idx`` (1, D, 1, 1)
    holds the release's ``96 / d``."""

    def __init__(self, candidates: np.ndarray, output_stride: int):
        super().__init__()
        inv = RELEASE_BF / np.asarray(candidates, np.float64)
        self.register_buffer("inv_dist_idx",
                             torch.tensor(inv, dtype=torch.float32).reshape(1, -1, 1, 1))
        self.output_stride = output_stride

    def forward(self, logits):
        if self.output_stride == 2:
            logits = F.interpolate(logits, scale_factor=2, mode="bilinear", align_corners=False)
        prob = torch.softmax(logits, dim=1)
        inv = (prob * self.inv_dist_idx).sum(1) / RELEASE_BF
        return prob, inv


class TorchTwin(nn.Module):
    """The whole network after the surrogate resampling, release names and layouts.

    ``config``: a :class:`gijax.nn.presets.ModelConfig` or the mapping of
    :func:`gijax.bench.torch_peer.twin_config`; ``candidates`` (D,) metres; ``offsets`` (H, W, 9, 2), the spherical
    layer's taps (:func:`gijax.nn.spherical.release_offsets` of the feature size), for
    spherical features only.
    """

    def __init__(self, config, candidates: np.ndarray, offsets: np.ndarray | None = None):
        super().__init__()
        cfg = twin_config(config)
        if np.shape(candidates) != (cfg["num_candidates"],):
            raise ValueError(f"model {cfg['name']!r} needs {cfg['num_candidates']} candidates; "
                             f"found shape {np.shape(candidates)}")
        self.cfg = cfg
        self.feature_extractor = FeatureExtractor(cfg, offsets)
        self.cv_builder = CostVolumeBuilder(cfg)
        self.cv_regulator = UNet(cfg["unet_in"], cfg["unet_base"])
        self.dist_regressor = DistanceRegressor(candidates, cfg["output_stride"])

    def forward(self, surrogates, masks, grids, grid_ok) -> dict:
        """surrogates (B, N, 3, Hs, Ws) in [0, 1], masks (B, N, Hm, Wm), grids (N, D, h, w, 2)
        normalised (x, y) over the feature map, grid_ok (N, D, h, w) bool -> dict of
        ``features``, ``cost_volume``, ``logits``, ``prob``, ``inv_distance`` (1/m)."""
        b, n = surrogates.shape[:2]
        feats = self.feature_extractor(surrogates.reshape(b * n, *surrogates.shape[2:]))
        c, hf, wf = feats.shape[1:]
        d, h, w = grids.shape[1:4]
        # Every camera of every sample at its own grid, the candidates stacked on the rows.
        grid = grids.reshape(1, n, d * h, w, 2).expand(b, -1, -1, -1, -1)
        grid = grid.reshape(b * n, d * h, w, 2)
        swept = F.grid_sample(feats, grid, mode="bilinear", padding_mode="zeros",
                              align_corners=False).reshape(b, n, c, d, h, w)
        seen = F.grid_sample(masks.reshape(b * n, 1, *masks.shape[2:]).to(feats.dtype), grid,
                             mode="bilinear", padding_mode="zeros", align_corners=False)
        valid = ((seen.reshape(b, n, d, h, w) > 0.0) & grid_ok[None]).to(feats.dtype)
        volume = self.cv_builder(swept, valid)
        logits = self.cv_regulator(volume)
        prob, inv = self.dist_regressor(logits)
        return {"features": feats.reshape(b, n, c, hf, wf), "cost_volume": volume,
                "logits": logits, "prob": prob, "inv_distance": inv}


# ------------------------------------------------------------------------------------ losses

def two_hot_target(distance, inv_candidates):
    """(B, D, H, W) two-hot target, linear in inverse distance between the bracketing
    candidates; labels clamped to the candidate range; ``inv_candidates`` (D,) 1/m,
    descending (as :func:`gijax.train.losses.two_hot_target`)."""
    n = inv_candidates.shape[0]
    ok = torch.isfinite(distance) & (distance > 0)
    far = 1.0 / inv_candidates[-1]
    x = (1.0 / torch.where(ok, distance, far)).clamp(inv_candidates[-1], inv_candidates[0])
    x = x[:, None]
    a = ((inv_candidates[None, :, None, None] >= x).sum(1) - 1).clamp(0, n - 2)
    q_a, q_b = inv_candidates[a][:, None], inv_candidates[a + 1][:, None]
    w_a = ((x - q_b) / (q_a - q_b)).clamp(0.0, 1.0)
    idx = torch.arange(n, device=distance.device)[None, :, None, None]
    a4 = a[:, None]
    zero = torch.zeros((), dtype=w_a.dtype, device=w_a.device)
    return torch.where(idx == a4, w_a, zero) + torch.where(idx == a4 + 1, 1.0 - w_a, zero)


def _label_mask(distance, valid):
    return (valid.bool() & torch.isfinite(distance) & (distance > 0)).to(torch.float32)


def volume_loss(prob, distance, valid, inv_candidates):
    """Binary cross-entropy between the probabilities and the two-hot target, averaged over
    usable pixels and candidates (as :func:`gijax.train.losses.volume_loss`)."""
    t = two_hot_target(distance, inv_candidates)
    m = _label_mask(distance, valid)[:, None]
    bce = -(t * torch.log(prob.clamp(min=PROB_FLOOR))
            + (1.0 - t) * torch.log((1.0 - prob).clamp(min=PROB_FLOOR)))
    count = m.sum() * prob.shape[1]
    return (bce * m).sum() / count.clamp(min=1.0)


def smooth_l1_loss(inv_pred, distance, valid, inv_candidates):
    """Mean smooth L1 (beta 1) between ``96 inv_pred`` and the clamped ``96 / d`` over usable
    pixels (as :func:`gijax.train.losses.smooth_l1_loss`)."""
    ok = torch.isfinite(distance) & (distance > 0)
    far = 1.0 / inv_candidates[-1]
    target = (1.0 / torch.where(ok, distance, far)).clamp(inv_candidates[-1], inv_candidates[0])
    m = _label_mask(distance, valid)
    err = F.smooth_l1_loss(RELEASE_BF * inv_pred, RELEASE_BF * target, reduction="none",
                           beta=1.0)
    return (err * m).sum() / m.sum().clamp(min=1.0)


def model_loss(twin: TorchTwin, out: dict, distance, valid):
    """The loss of the twin's config (``'volume'`` or ``'smooth_l1'``) on its outputs."""
    inv_cand = twin.dist_regressor.inv_dist_idx.reshape(-1) / RELEASE_BF
    if twin.cfg["loss"] == "volume":
        return volume_loss(out["prob"], distance, valid, inv_cand)
    return smooth_l1_loss(out["inv_distance"], distance, valid, inv_cand)


def numpy_state_dict(twin: nn.Module) -> dict[str, np.ndarray]:
    """The twin's state dict as numpy arrays, release names (what
    :func:`gijax.nn.release_weights.load_state_dict` reads)."""
    return {k: v.detach().cpu().numpy() for k, v in twin.state_dict().items()}


# ------------------------------------------------------------------------- benchmark steps

def tensors(inputs: Mapping[str, np.ndarray]) -> dict:
    """The arrays of :func:`gijax.bench.torch_peer.peer_inputs` as the twin takes them
    (copies; surrogates channels first)."""
    x = {k: torch.from_numpy(np.array(inputs[k]))
         for k in ("masks", "grids", "grid_ok", "distance", "valid")}
    x["surrogates"] = torch.from_numpy(np.ascontiguousarray(
        np.moveaxis(inputs["surrogates"], -1, 2)))
    return x


def inference(twin: TorchTwin, inputs: Mapping[str, np.ndarray]):
    """``run()``: one eval-mode forward of ``twin`` on ``inputs`` (no autograd); returns the
    inverse distance."""
    x = tensors(inputs)
    twin.eval()

    def run():
        with torch.inference_mode():
            return twin(x["surrogates"], x["masks"], x["grids"], x["grid_ok"])["inv_distance"]

    return run


def train_step(twin: TorchTwin, inputs: Mapping[str, np.ndarray], lr: float = 1e-4):
    """``run()``: one optimiser step of ``twin`` on ``inputs`` (train-mode BatchNorm, the
    config's loss, backward, ``torch.optim.Adam(lr)``); returns (loss, gradient norm) before
    the update, as floats."""
    x = tensors(inputs)
    twin.train()
    params = [p for p in twin.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params, lr=lr)

    def run():
        opt.zero_grad(set_to_none=True)
        out = twin(x["surrogates"], x["masks"], x["grids"], x["grid_ok"])
        loss = model_loss(twin, out, x["distance"], x["valid"])
        loss.backward()
        norm = torch.linalg.vector_norm(
            torch.stack([torch.linalg.vector_norm(p.grad) for p in params]))
        opt.step()
        return float(loss.detach()), float(norm)

    return run
