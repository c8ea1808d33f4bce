"""The sweep as the network runs it: its two grid pytrees, and batches sampled at them.

Grids are the boundary between geometry and network. Two pytrees of arrays hold them, each made
by one pure, traceable function from the rig and static sizes (panoramas and (h, w) tuples; the
model layer turns a model's config into those sizes, :func:`gijax.model.model_grids`):

* :class:`SurrogateMaps` (:func:`surrogate_resampling`): per camera, the fisheye pixel of every
  surrogate pixel and whether the lens sees it. They depend on the intrinsics only;
  :func:`fisheye_surrogates` turns a batch of raw fisheye images into the surrogate images
  the network consumes (the data loader does the same per sample on its own threads);
* :class:`SweepGrids` (:func:`sweep_grids`): per camera, the feature-map pixel of every
  (candidate, cost cell) point and its validity, the candidates, and, for a network with the
  guided refinement, the surrogate pixel of every (candidate, output pixel) point; for a network
  with the matching cost, the surrogate pixel of every (candidate, sub-cell) point, ``k x k``
  per cost cell (:func:`match_grids`).

:func:`sweep_features` samples a batch of feature maps and masks at the sweep grids (the sweep
stage of the network), :func:`sweep_colours` a batch of surrogate images and masks at the
guide grids and :func:`match_grey` at the match grids. A camera counts for a point when the grid point is valid for it and its sampled
mask is above :data:`MASK_THRESHOLD` (any overlap with the seen region, as in the release).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import Rig
from gijax.sweep.grid import rescale_pixels, sweep_grid
from gijax.sweep.sample import sample_sweep
from gijax.sweep.surrogate import resample_surrogates, surrogate_maps

Array = jax.Array

# A camera sees a sweep point when its bilinearly sampled mask is above this (the release's
# rule: any overlap with a seen pixel counts).
MASK_THRESHOLD = 0.0


@dataclasses.dataclass(frozen=True)
class SurrogateMaps:
    """Where each camera's surrogate image reads its fisheye image (a pytree of arrays).

    Attributes:
      fisheye_px: (N, Hs, Ws, 2) fisheye pixel (u, v) of every surrogate pixel.
      fisheye_ok: (N, Hs, Ws) bool, the surrogate pixel is inside the lens image.
    """

    fisheye_px: Array
    fisheye_ok: Array


@dataclasses.dataclass(frozen=True)
class SweepGrids:
    """Where the sweep samples each camera for one rig and candidate list (a pytree of arrays).

    Attributes:
      sweep_px: (N, D, h, w, 2) feature-map pixel (col, row) of every (candidate, cell) point.
      sweep_ok: (N, D, h, w) bool, the point is in front of and seen by that camera's lens.
      candidates: (D,) ascending distances, metres.
      guide_px: (N, D, H, W, 2) surrogate pixel (col, row) of every (candidate, output pixel)
        point, for a network with the guided refinement; else None.
      guide_ok: (N, D, H, W) bool, the point is in front of and seen by that camera's lens;
        None with ``guide_px``.
      match_px: (N, D, k h, k w, 2) surrogate pixel (col, row) of every (candidate, sub-cell)
        point, ``k x k`` sub-cells per cost cell, for a network with the matching cost; else None.
      match_ok: (N, D, k h, k w) bool, the point is in front of and seen by that camera's lens;
        None with ``match_px``.
    """

    sweep_px: Array
    sweep_ok: Array
    candidates: Array
    guide_px: Array | None = None
    guide_ok: Array | None = None
    match_px: Array | None = None
    match_ok: Array | None = None


jax.tree_util.register_dataclass(SurrogateMaps, data_fields=["fisheye_px", "fisheye_ok"],
                                 meta_fields=[])
jax.tree_util.register_dataclass(
    SweepGrids, data_fields=["sweep_px", "sweep_ok", "candidates", "guide_px", "guide_ok",
                             "match_px", "match_ok"],
    meta_fields=[])


def cost_panorama(pano: Panorama, stride: int = 2) -> Panorama:
    """The cost-volume panorama of an output panorama: the same latitudes at ``1 / stride``
    the size (a model's ``output_stride``)."""
    return Panorama(pano.height // stride, pano.width // stride, pano.lat_min, pano.lat_max)


def surrogate_resampling(rig: Rig, surrogate_hw: tuple[int, int]) -> SurrogateMaps:
    """The :class:`SurrogateMaps` of ``rig`` (at the network's image size) for surrogate
    hemispheres of ``surrogate_hw`` = (height, width) pixels."""
    return SurrogateMaps(*surrogate_maps(rig, Panorama.hemisphere(*surrogate_hw)))


def guide_grids(rig: Rig, candidates: Array, output_pano: Panorama,
                surrogate_hw: tuple[int, int]) -> tuple[Array, Array]:
    """(N, D, H, W, 2) surrogate pixels and (N, D, H, W) validity of the sweep of ``rig`` at
    ``candidates`` (D,) metres over the output panorama itself: where the guided refinement
    reads the cameras' colours (:mod:`gijax.nn.refine`)."""
    return sweep_grid(rig, candidates, output_pano, Panorama.hemisphere(*surrogate_hw))


def match_grids(rig: Rig, candidates: Array, cost_pano: Panorama,
                surrogate_hw: tuple[int, int], samples: int) -> tuple[Array, Array]:
    """(N, D, k h, k w, 2) surrogate pixels and (N, D, k h, k w) validity of the sweep of
    ``rig`` at ``candidates`` (D,) metres over the cost panorama ``cost_pano`` (h x w cells)
    subdivided ``k = samples`` times along each side: the centres of the ``k x k`` equal
    sub-cells of every cost cell (a panorama of k h x k w pixels over the same latitudes nests
    its pixels in the cells), where the matching cost reads the cameras' colours
    (:mod:`gijax.sweep.matching`)."""
    if samples < 1:
        raise ValueError(f"the match grids need at least 1 sample per cell side; found {samples}")
    fine = Panorama(cost_pano.height * samples, cost_pano.width * samples, cost_pano.lat_min,
                    cost_pano.lat_max)
    return sweep_grid(rig, candidates, fine, Panorama.hemisphere(*surrogate_hw))


def sweep_grids(rig: Rig, candidates: Array, cost_pano: Panorama, feature_hw: tuple[int, int],
                guide_pano: Panorama | None = None,
                surrogate_hw: tuple[int, int] | None = None,
                match_samples: int = 0) -> SweepGrids:
    """The :class:`SweepGrids` of ``rig`` (at the network's image size) at ``candidates`` (D,)
    metres, over the cost-volume panorama ``cost_pano`` (oriented by the rig's panorama frame)
    into feature maps of ``feature_hw`` = (height, width).

    With ``guide_pano`` (the output panorama) and ``surrogate_hw`` the guide grids of the
    guided refinement are made too (:func:`guide_grids`); with ``match_samples`` = k > 0 and
    ``surrogate_hw`` the match grids of the matching cost (:func:`match_grids`). The candidates
    are kept in the rig's precision. Pure and traceable: evaluated once for a fixed rig, or
    inside jit when the rig is an input.
    """
    if guide_pano is not None and surrogate_hw is None:
        raise ValueError("guide grids need both the output panorama and the surrogate size")
    if match_samples and surrogate_hw is None:
        raise ValueError("match grids need the surrogate size")
    candidates = jnp.asarray(candidates, rig.translations.dtype)
    px, ok = sweep_grid(rig, candidates, cost_pano, Panorama.hemisphere(*feature_hw))
    guide = ((None, None) if guide_pano is None
             else guide_grids(rig, candidates, guide_pano, surrogate_hw))
    match = ((None, None) if not match_samples
             else match_grids(rig, candidates, cost_pano, surrogate_hw, match_samples))
    return SweepGrids(px, ok, candidates, *guide, *match)


def _fold_batch(x: Array) -> Array:
    """(B, N, H, W, C) -> (N, H, W, B C): one gather per camera serves the whole batch."""
    b, n, h, w, c = x.shape
    return jnp.transpose(x, (1, 2, 3, 0, 4)).reshape(n, h, w, b * c)


def _unfold_batch(x: Array, b: int) -> Array:
    """(N, ..., B C) -> (B, N, ..., C)."""
    n, rest, bc = x.shape[0], x.shape[1:-1], x.shape[-1]
    x = x.reshape(n, *rest, b, bc // b)
    return jnp.moveaxis(x, -2, 0)


def fisheye_surrogates(maps: SurrogateMaps, images: Array, masks: Array) -> tuple[Array, Array]:
    """Raw fisheye images (B, N, h, w, 3) float in [0, 1] and masks (B, N, h, w) (1 = the pixel
    sees the world) -> surrogate images (B, N, Hs, Ws, 3) and their masks (B, N, Hs, Ws),
    0 outside the lens (see :func:`gijax.sweep.surrogate.resample_surrogate`)."""
    b = images.shape[0]
    dtype = images.dtype
    # Colours and mask of all samples in one gather per camera.
    stacked = _fold_batch(jnp.concatenate([images, masks[..., None].astype(dtype)], axis=-1))
    sampled, _ = resample_surrogates(maps.fisheye_px.astype(dtype), maps.fisheye_ok, stacked)
    sampled = _unfold_batch(sampled, b)                              # (B, N, Hs, Ws, 4)
    # Channel 3 is the resampled mask, already 0 outside the lens.
    return sampled[..., :3], sampled[..., 3]


def sweep_features(features: Array, masks: Array, grids: SweepGrids,
                   boundary: str = "zeros") -> tuple[Array, Array]:
    """Per-camera features (B, N, hf, wf, C) and masks (B, N, Hm, Wm) sampled at the sweep grids
    by ``boundary`` (:mod:`gijax.sweep.sample`): (B, N, D, h, w, C) and per-camera validity
    (B, N, D, h, w) bool (grid point valid and sampled mask > :data:`MASK_THRESHOLD`). Masks of
    any size are sampled at the same directions."""
    b = features.shape[0]
    dtype = features.dtype
    coords = grids.sweep_px.astype(dtype)
    swept = _unfold_batch(sample_sweep(_fold_batch(features), coords, boundary), b)
    # The same directions in the mask's own pixels (as normalised grid_sample coordinates do).
    mask_coords = rescale_pixels(coords, features.shape[2:4], masks.shape[2:4])
    swept_mask = sample_sweep(jnp.moveaxis(masks.astype(dtype), 0, -1), mask_coords, boundary)
    swept_mask = jnp.moveaxis(swept_mask, -1, 0)                     # (B, N, D, h, w)
    return swept, grids.sweep_ok[None] & (swept_mask > MASK_THRESHOLD)


def sweep_colours(surrogates: Array, masks: Array, grids: SweepGrids,
                  boundary: str = "zeros") -> tuple[Array, Array]:
    """Surrogate images (B, N, Hs, Ws, 3) and masks (B, N, Hs, Ws) sampled at the guide grids:
    colours (B, N, D, H, W, 3) and whether each camera sees each point (B, N, D, H, W), in the
    images' dtype (guide point valid and sampled mask > :data:`MASK_THRESHOLD`)."""
    if grids.guide_px is None:
        raise ValueError("these sweep grids have no guide grids (made without the output "
                         "panorama and the surrogate size)")
    colours, seen = _sample_with_seen(surrogates, masks, grids.guide_px, grids.guide_ok,
                                      boundary, "the guided refinement")
    return jnp.moveaxis(colours, -2, 0), jnp.moveaxis(seen, -1, 0)


def match_grey(surrogates: Array, masks: Array, grids: SweepGrids,
               boundary: str = "zeros", batch_last: bool = False) -> tuple[Array, Array]:
    """Surrogate images (B, N, Hs, Ws, 3) and masks (B, N, Hs, Ws) sampled at the match grids:
    grey levels (the mean of the three channels) (B, N, D, k h, k w) and whether each camera
    sees each point (B, N, D, k h, k w), in the images' dtype (match point valid and sampled
    mask > :data:`MASK_THRESHOLD`). The grey level is taken before sampling (bilinear sampling
    is linear), so one gather moves two values a sample, not four.

    ``batch_last``: both as (N, D, k h, k w, B), the layout the gather makes (the batch folded
    into the channels, :func:`_fold_batch`) and :func:`gijax.sweep.matching.cell_zncc_batch_last`
    reads, so that the samples are never transposed."""
    if grids.match_px is None:
        raise ValueError("these sweep grids have no match grids (made without match samples)")
    # A sum, not a mean: ReduceMean's axes are an attribute at the export's opset 17.
    grey = jnp.sum(surrogates, axis=-1, keepdims=True) * (1.0 / surrogates.shape[-1])
    values, seen = _sample_with_seen(grey, masks, grids.match_px, grids.match_ok, boundary,
                                     "the matching cost")
    values = values[..., 0]
    if batch_last:
        return values, seen
    return jnp.moveaxis(values, -1, 0), jnp.moveaxis(seen, -1, 0)


def _sample_with_seen(values: Array, masks: Array, px: Array, ok: Array, boundary: str,
                      who: str) -> tuple[Array, Array]:
    """Images (B, N, Hs, Ws, C) and masks (B, N, Hs, Ws) at surrogate pixels ``px``
    (N, ..., 2) valid where ``ok``: (N, ..., B, C) values and (N, ..., B) seen (valid and
    sampled mask > :data:`MASK_THRESHOLD`), batch last as the gather makes them: the batch's
    values and masks are folded into the channels, one gather per camera for all of them."""
    if tuple(masks.shape[2:4]) != tuple(values.shape[2:4]):
        raise ValueError(f"{who} reads masks at the surrogates' size "
                         f"{tuple(values.shape[2:4])}; found {tuple(masks.shape[2:4])}")
    b, c = values.shape[0], values.shape[-1]
    dtype = values.dtype
    stacked = jnp.concatenate([_fold_batch(values), _fold_batch(masks[..., None].astype(dtype))],
                              axis=-1)
    sampled = sample_sweep(stacked, px.astype(dtype), boundary)     # (N, ..., B C + B)
    out = sampled[..., :b * c].reshape(*sampled.shape[:-1], b, c)
    seen = (ok[..., None] & (sampled[..., b * c:] > MASK_THRESHOLD)).astype(dtype)
    return out, seen
