"""The whole network: raw fisheye images -> surrogate images -> shared features -> sphere sweep
-> cost volume -> 3D U-Net -> soft-argmax in inverse distance.

Grids are the boundary between geometry and network. Two pure functions, and nothing else, run
a model anywhere in gijax (training, the data loader, predict, evaluation, the ONNX export):

* :func:`make_grids` (rig, candidates, config) -> :class:`Grids`: the surrogate-resampling maps
  (per camera, the fisheye pixel of every surrogate pixel) and the sweep grids (per camera, the
  feature-map pixel of every (candidate, cell) point and its validity), with the candidates;
* :func:`forward` (model, images, masks, grids): the network from raw images. It is
  :func:`gijax.sweep.surrogate.resample_surrogates` (the first stage, which the data loader runs
  on its own threads) followed by :func:`forward_surrogates` (everything after it).

Shapes for one call (B samples, N cameras, D candidates; paper size in brackets, see
``docs/model.md``):

* surrogates (B, N, Hs, Ws, 3) [512 x 2048] and their masks (B, N, Hm, Wm), at the surrogate
  resolution or any other (the release feeds masks at the feature resolution): mask sweep
  coordinates are rescaled to the mask's own size;
* features (B, N, Hs/4, Ws/4, C) [128 x 512 x 16], one extractor shared by all cameras;
* sweep grids (N, D, h, w, 2) feature-map pixels (col, row) over the rig panorama [80 x 320 for
  the hemisphere], oriented by the rig's panorama frame
  (:mod:`gijax.geometry.panorama_frame`); any panorama whose cost grid halves three times runs
  (:func:`model_panorama`: the model's own coverage or the other one);
  features and masks are sampled there by ``config.sweep_boundary``;
* cost volume (B, D, h, w, unet_in) [48 concat / 16 variance], U-Net logits (B, D, h, w);
* outputs at (H, W) = 2 (h, w) [160 x 640]: inverse distance (1/m), distance (m), probabilities
  (B, D, H, W), entropy (nats) and ``valid``.

A camera counts for a cell when the grid point is valid for it and its sampled mask is > 0 (any
overlap with the seen region, as in the release). The candidates are data, not weights: a list of
the same length can replace the training list at inference. Variance models accept any number
of cameras (at least two).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from gijax.geometry.panorama import Panorama
from gijax.geometry.panorama_frame import coverage_of, panorama_of
from gijax.geometry.rig import Rig
from gijax.nn import (Conv3D, FeatureExtractor, ModelConfig, get_preset, make_cost_volume,
                      make_unet, regress)
from gijax.nn.refine import GuidedRefinement, colour_guide
from gijax.sweep.grid import rescale_pixels, sweep_grid
from gijax.sweep.sample import sample_sweep
from gijax.sweep.surrogate import resample_surrogates, surrogate_maps

Array = jax.Array

# A camera sees a sweep point when its bilinearly sampled mask is above this (the release's
# rule: any overlap with a seen pixel counts).
MASK_THRESHOLD = 0.0


@dataclasses.dataclass(frozen=True)
class Grids:
    """Sampling grids of one rig and candidate list for one model size (a pytree of arrays).

    Attributes:
      surrogate_px: (N, Hs, Ws, 2) raw-image pixel (u, v) of every surrogate pixel.
      surrogate_ok: (N, Hs, Ws) bool, the surrogate pixel is inside the lens image.
      sweep_px: (N, D, h, w, 2) feature-map pixel (col, row) of every (candidate, cell) point.
      sweep_ok: (N, D, h, w) bool, the point is in front of and seen by that camera's lens.
      candidates: (D,) ascending distances, metres.
      guide_px: (N, D, H, W, 2) surrogate pixel (col, row) of every (candidate, output pixel)
        point, for a model with the guided refinement (``config.refine``); else None.
      guide_ok: (N, D, H, W) bool, the point is in front of and seen by that camera's lens.
    """

    surrogate_px: Array
    surrogate_ok: Array
    sweep_px: Array
    sweep_ok: Array
    candidates: Array
    guide_px: Array | None = None
    guide_ok: Array | None = None


jax.tree_util.register_dataclass(
    Grids, data_fields=["surrogate_px", "surrogate_ok", "sweep_px", "sweep_ok", "candidates",
                        "guide_px", "guide_ok"],
    meta_fields=[])


def model_rig(rig: Rig) -> Rig:
    """The rig as the network needs it: its static masks are not used inside the model (per
    sample masks are an input), so they are dropped to keep them out of every call's arguments."""
    return rig.replace(masks=tuple(None for _ in rig.masks))


def model_panorama(config: ModelConfig, coverage: str | None = None) -> Panorama:
    """The output panorama of ``config`` for ``coverage`` ('hemisphere' or 'sphere'; None: the
    coverage it was trained on). Its own coverage is ``config.output_hw``; the other one keeps
    the angular resolution (the sphere has twice the hemisphere's rows)."""
    coverage = coverage or config.panorama
    h, w = config.output_hw
    hemi_hw = (h // 2, w) if config.panorama == "sphere" else (h, w)
    pano = panorama_of(coverage, hemi_hw)
    _check_output_panorama(config, pano)
    return pano


def cost_panorama(pano: Panorama, stride: int = 2) -> Panorama:
    """The cost-volume panorama of an output panorama: the same latitudes at ``1 / stride``
    the size (a model's ``output_stride``)."""
    return Panorama(pano.height // stride, pano.width // stride, pano.lat_min, pano.lat_max)


def _check_output_panorama(config: ModelConfig, pano: Panorama) -> None:
    h, w = pano.shape
    m = 8 * config.output_stride
    if h % m or w % m:
        part = "half the output" if config.output_stride == 2 else "the output's size"
        raise ValueError(f"model {config.name!r}: an output panorama of {h} x {w} cannot run; "
                         f"both sides must be divisible by {m} (the cost volume is {part} "
                         f"and the U-Net halves it three times)")


def sweep_grids(rig: Rig, candidates: Array, config: ModelConfig,
                pano: Panorama | None = None) -> tuple[Array, Array]:
    """(N, D, h, w, 2) feature-map pixels and (N, D, h, w) validity of the sweep of ``rig`` at
    ``candidates`` (D,) metres, for ``config``'s feature size and the cost volume of the output
    panorama ``pano`` (default :func:`model_panorama`), oriented by the rig's panorama frame."""
    pano = model_panorama(config) if pano is None else pano
    _check_output_panorama(config, pano)
    return sweep_grid(rig, candidates, cost_panorama(pano, config.output_stride),
                      Panorama.hemisphere(*config.feature_hw))


def guide_grids(rig: Rig, candidates: Array, config: ModelConfig,
                pano: Panorama | None = None) -> tuple[Array, Array]:
    """(N, D, H, W, 2) surrogate pixels and (N, D, H, W) validity of the sweep of ``rig`` at
    ``candidates`` over the output panorama ``pano`` itself (default :func:`model_panorama`):
    where the guided refinement reads the cameras' colours (:mod:`gijax.nn.refine`)."""
    pano = model_panorama(config) if pano is None else pano
    _check_output_panorama(config, pano)
    return sweep_grid(rig, candidates, pano, Panorama.hemisphere(*config.surrogate_hw))


def make_grids(rig: Rig, candidates: Array, config: ModelConfig,
               pano: Panorama | None = None) -> Grids:
    """Every grid the network needs for ``rig`` (at the model's image size, i.e. intrinsics
    already scaled by ``config.image_scale``), ``candidates`` (D,) metres and the output
    panorama ``pano`` (static; default :func:`model_panorama`, the coverage the model was
    trained on). Pure and traceable: evaluated once for a fixed rig, or inside jit when the
    rig is an input."""
    check_candidates(config, candidates)
    candidates = jnp.asarray(candidates, rig.translations.dtype)
    sur_px, sur_ok = surrogate_maps(rig, Panorama.hemisphere(*config.surrogate_hw))
    px, ok = sweep_grids(rig, candidates, config, pano)
    guide = guide_grids(rig, candidates, config, pano) if config.refine else (None, None)
    return Grids(sur_px, sur_ok, px, ok, candidates, *guide)


def coverage_note(config: ModelConfig, pano: Panorama) -> str | None:
    """A warning when ``pano`` covers another part of the sphere than ``config`` was trained
    on (the network then sees latitudes it never saw), else None."""
    asked = coverage_of(pano)
    if asked == config.panorama:
        return None
    return (f"warning: model {config.name!r} was trained on the {config.panorama}; it is run "
            f"on the {asked} here, whose other latitudes it has never seen")


def check_candidates(config: ModelConfig, candidates) -> None:
    """ValueError unless ``candidates`` is (num_candidates,), and, when its values are known
    (not traced), finite, positive and strictly ascending."""
    shape = tuple(np.shape(candidates))
    if shape != (config.num_candidates,):
        raise ValueError(f"model {config.name!r} needs {config.num_candidates} candidates of shape "
                         f"({config.num_candidates},); found shape {shape}")
    if isinstance(candidates, jax.core.Tracer):
        return
    from gijax.candidates.validation import check_candidates as check_list

    check_list(candidates)


def check_surrogates(config: ModelConfig, surrogates, masks, num_cameras: int) -> None:
    """ValueError naming the argument, expected and found shape for any mismatch."""
    shape = tuple(np.shape(surrogates))
    hs, ws = config.surrogate_hw
    if len(shape) != 5 or shape[2:] != (hs, ws, 3):
        raise ValueError(f"surrogates must have shape (batch, cameras, {hs}, {ws}, 3) for model "
                         f"{config.name!r}; found {shape}")
    n = shape[1]
    if n != num_cameras:
        raise ValueError(f"the rig has {num_cameras} cameras but {n} surrogate images were "
                         f"given")
    if config.cost_volume == "concat" and n != config.num_cameras:
        raise ValueError(f"model {config.name!r} concatenates exactly {config.num_cameras} cameras;"
                         f" found {n} (variance models accept any number)")
    if n < 2:
        raise ValueError(f"stereo needs at least 2 cameras; found {n}")
    mshape = tuple(np.shape(masks))
    if len(mshape) != 4 or mshape[:2] != shape[:2]:
        raise ValueError(f"masks must have shape ({shape[0]}, {shape[1]}, height, width) (batch, "
                         f"cameras, height, width); found {mshape}")


def forward_surrogates(model: "OmniStereoNet", surrogates: Array, masks: Array,
                       grids: Grids) -> dict:
    """The network from surrogate images (B, N, Hs, Ws, 3) in [0, 1] and masks (B, N, Hm, Wm).

    Only ``grids.sweep_px``, ``sweep_ok`` and ``candidates`` are read. Returns
    ``inv_distance`` (B, H, W) 1/m, ``distance`` (B, H, W) m, ``prob`` (B, D, H, W), ``entropy``
    (B, H, W) nats, ``logits`` (B, D, h, w) (the U-Net output) and ``valid`` (B, H, W) bool: the
    cell is seen by at least two cameras (variance) or by every camera (concat) at every
    candidate.
    """
    cfg = model.config
    check_surrogates(cfg, surrogates, masks, grids.sweep_px.shape[0])
    b, n, hs, ws, _ = surrogates.shape
    dtype = surrogates.dtype
    feats = model.features(surrogates.reshape(b * n, hs, ws, 3))
    feats = feats.reshape(b, n, *feats.shape[1:])                   # (B, N, hf, wf, C)
    sampled, cam_valid = sweep(feats, masks, grids, cfg.sweep_boundary)
    volume = model.cost_volume(sampled, cam_valid.astype(dtype))
    logits = model.unet(volume)
    # The output is output_stride x the cost grid, whichever panorama the grids cover.
    k = cfg.output_stride
    h, w = logits.shape[2:4]
    out = dict(regress(logits, grids.candidates.astype(dtype), (k * h, k * w)))
    out["logits"] = logits
    if cfg.refine:
        out.update(_refined(model, surrogates, masks, grids, out, dtype))
    needed = 2 if cfg.cost_volume == "variance" else n
    # Float reductions: TensorRT reduces float tensors only (no integer / boolean ReduceSum).
    seen_by = jnp.min(jnp.sum(cam_valid.astype(dtype), axis=1), axis=1)   # (B, h, w)
    cell_ok = seen_by >= needed
    out["valid"] = jnp.repeat(jnp.repeat(cell_ok, k, axis=1), k, axis=2)
    return out


def _refined(model: "OmniStereoNet", surrogates: Array, masks: Array, grids: Grids, out: dict,
             dtype) -> dict:
    """The guided refinement's outputs: ``inv_distance`` and ``distance`` refined, the
    soft-argmax estimate kept as ``inv_distance_coarse``."""
    if grids.guide_px is None:
        raise ValueError(f"model {model.config.name!r} refines its estimate and needs the guide "
                         f"grids (gijax.model.guide_grids) in its Grids")
    b = surrogates.shape[0]
    # Colours and masks of all samples in one gather per camera, at the surrogate's size.
    sur_masks = masks
    if tuple(masks.shape[2:4]) != tuple(surrogates.shape[2:4]):
        raise ValueError(f"the guided refinement reads masks at the surrogates' size "
                         f"{tuple(surrogates.shape[2:4])}; found {tuple(masks.shape[2:4])}")
    stacked = _fold_batch(jnp.concatenate([surrogates, sur_masks[..., None].astype(dtype)], -1))
    sampled = _unfold_batch(sample_sweep(stacked, grids.guide_px.astype(dtype),
                                         model.config.sweep_boundary), b)  # (B, N, D, H, W, 4)
    seen = (grids.guide_ok[None] & (sampled[..., 3] > MASK_THRESHOLD)).astype(dtype)
    prob = jax.lax.stop_gradient(out["prob"])
    guide = colour_guide(sampled[..., :3], seen, prob)
    cand = grids.candidates.astype(dtype)
    coarse = jax.lax.stop_gradient(out["inv_distance"])
    inv = model.refine(coarse, jax.lax.stop_gradient(out["entropy"]), guide,
                       (1.0 / cand[-1], 1.0 / cand[0]))
    return {"inv_distance": inv, "distance": 1.0 / inv, "inv_distance_coarse": out["inv_distance"]}


def _fold_batch(x: Array) -> Array:
    """(B, N, H, W, C) -> (N, H, W, B C): one gather per camera serves the whole batch."""
    b, n, h, w, c = x.shape
    return jnp.transpose(x, (1, 2, 3, 0, 4)).reshape(n, h, w, b * c)


def _unfold_batch(x: Array, b: int) -> Array:
    """(N, ..., B C) -> (B, N, ..., C)."""
    n, rest, bc = x.shape[0], x.shape[1:-1], x.shape[-1]
    x = x.reshape(n, *rest, b, bc // b)
    return jnp.moveaxis(x, -2, 0)


def sweep(features: Array, masks: Array, grids: Grids, boundary: str) -> tuple[Array, Array]:
    """Per-camera features (B, N, hf, wf, C) and masks (B, N, Hm, Wm) sampled at the sweep grid:
    (B, N, D, h, w, C) and per-camera validity (B, N, D, h, w) bool (grid point valid and
    sampled mask > :data:`MASK_THRESHOLD`)."""
    b = features.shape[0]
    dtype = features.dtype
    coords = grids.sweep_px.astype(dtype)
    swept = _unfold_batch(sample_sweep(_fold_batch(features), coords, boundary), b)
    # The same directions in the mask's own pixels (as normalised grid_sample coordinates do).
    mask_coords = rescale_pixels(coords, features.shape[2:4], masks.shape[2:4])
    swept_mask = sample_sweep(jnp.moveaxis(masks.astype(dtype), 0, -1), mask_coords, boundary)
    swept_mask = jnp.moveaxis(swept_mask, -1, 0)                     # (B, N, D, h, w)
    return swept, grids.sweep_ok[None] & (swept_mask > MASK_THRESHOLD)


def forward(model: "OmniStereoNet", images: Array, masks: Array, grids: Grids) -> dict:
    """The network from raw fisheye images (B, N, h, w, 3) float RGB in [0, 1] and masks
    (B, N, h, w) (1 = the pixel sees the world) at the model's image size; see
    :func:`forward_surrogates` for the outputs. The model must be in the mode wanted (eval for
    inference)."""
    b = images.shape[0]
    dtype = images.dtype
    # Colours and mask of all samples in one gather per camera.
    stacked = _fold_batch(jnp.concatenate([images, masks[..., None].astype(dtype)], axis=-1))
    sampled, _ = resample_surrogates(grids.surrogate_px.astype(dtype), grids.surrogate_ok, stacked)
    sampled = _unfold_batch(sampled, b)                              # (B, N, Hs, Ws, 4)
    # Channel 3 is the resampled mask, already 0 outside the lens.
    return forward_surrogates(model, sampled[..., :3], sampled[..., 3], grids)


class OmniStereoNet(nnx.Module):
    """Omnidirectional stereo from N per-camera surrogate images (see the module docstring)."""

    def __init__(self, config: ModelConfig, rngs: nnx.Rngs):
        self.config = config
        self.features = FeatureExtractor(config, rngs)
        self.cost_volume = make_cost_volume(config, rngs)
        self.unet = make_unet(config, rngs)
        self.refine = GuidedRefinement(config.num_candidates, rngs) if config.refine else None

    def __call__(self, surrogates: Array, masks: Array, rig: Rig, candidates: Array,
                 pano: Panorama | None = None) -> dict:
        """surrogates (B, N, Hs, Ws, 3) in [0, 1], masks (B, N, Hm, Wm), candidates (D,) metres:
        :func:`forward_surrogates` with the sweep grids of ``rig`` computed here for the output
        panorama ``pano`` (static; default :func:`model_panorama`)."""
        check_candidates(self.config, candidates)
        found = tuple(np.shape(surrogates))[1:2]
        if found != (rig.num_cameras,):
            raise ValueError(f"the rig has {rig.num_cameras} cameras but "
                             f"{found[0] if found else 'no'} surrogate images were given")
        candidates = jnp.asarray(candidates, surrogates.dtype)
        px, ok = sweep_grids(rig, candidates, self.config, pano)
        guide = (guide_grids(rig, candidates, self.config, pano) if self.config.refine
                 else (None, None))
        grids = Grids(None, None, px, ok, candidates, *guide)
        return forward_surrogates(self, surrogates, masks, grids)


def create_model(name_or_config: str | ModelConfig, seed: int = 0) -> OmniStereoNet:
    """A freshly initialised :class:`OmniStereoNet` from a preset name (e.g. 'G16VV-cpu') or a
    :class:`~gijax.nn.presets.ModelConfig`: exactly ``OmniStereoNet(config, nnx.Rngs(seed))``.

    Kernels are LeCun-normal (:func:`gijax.nn.layers.kernel_init`, which keeps eager
    construction of a paper-size network to seconds on a CPU); biases and BatchNorm shifts and
    running means start at 0, BatchNorm scales and running variances at 1.
    """
    config = get_preset(name_or_config) if isinstance(name_or_config, str) else name_or_config
    if not isinstance(config, ModelConfig):
        raise ValueError(f"expected a preset name or a ModelConfig; found "
                         f"{type(name_or_config).__name__}")
    return OmniStereoNet(config, nnx.Rngs(seed))


def with_conv3d(model: OmniStereoNet, conv3d: str) -> OmniStereoNet:
    """A copy of ``model`` whose 3-D convolutions lower as ``conv3d`` ('auto', 'split' or
    'native', see :class:`~gijax.nn.presets.ModelConfig`), its config saying so, with the same
    variable values (arrays shared, not copied) and train / eval mode; ``model`` is unchanged.

    The lowering is part of the module graph, so a function jitted for one model is traced
    anew for the copy. The ONNX exporter uses this to emit one Conv node per 3-D conv from a
    model trained with the CPU's split lowering.
    """
    config = dataclasses.replace(model.config, conv3d=conv3d)   # validates the name
    graphdef, state = nnx.split(model)
    copy = nnx.merge(graphdef, state)
    copy.config = config
    for _, module in nnx.iter_modules(copy):
        if isinstance(module, Conv3D):
            module.lowering = conv3d
    return copy
