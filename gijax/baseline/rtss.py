"""Real-time sphere-sweep stereo (RTSS, Meuleman et al. 2021): the classical, non-learning baseline.

Pipeline, for every reference camera ``r`` (all cameras by default):

1. every camera's image is resampled to its matching view (:mod:`gijax.baseline.views`);
2. per reference pixel, the partner camera with the largest displacement between the nearest
   and the farthest candidate (:mod:`gijax.baseline.camera_select`, pure geometry);
3. per candidate a matching cost against the partner image warped bilinearly (4-neighbour
   gather): by default the zero-mean normalised cross-correlation of 7x7 patches (a departure
   from RTSS that survives per-camera exposure and sensor noise), or with ``cost='ad'`` the
   original ``min(sum_RGB |ref - warped|, cost_clamp)`` on single pixels
   (:mod:`gijax.baseline.matching_cost`); candidates the partner cannot see cost ``cost_clamp``;
4. every cost slice filtered by the edge-aware pyramid guided by the reference view
   (:mod:`gijax.baseline.cost_filter`);
5. winner-take-all, parabola refinement, fractional index to inverse distance through the
   actual candidate list (:mod:`gijax.baseline.winner`);
6. the reference maps re-expressed at the rig's reference point and blended in inverse
   distance, small holes filled, unseeable pixels invalid (:mod:`gijax.baseline.stitch`).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from gijax.checks import bad_field
from gijax.baseline.camera_select import item_at, select_best_camera, sweep_coords
from gijax.baseline.cost_filter import edge_aware_filter
from gijax.baseline.matching_cost import COST_KINDS, matching_cost
from gijax.baseline.stitch import stitch
from gijax.baseline.views import MatchView, view_image
from gijax.baseline.winner import winner_take_all
from gijax.candidates.validation import guard_candidates
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import Rig, is_homogeneous, map_cameras
from gijax.sampling import bilinear_sample
from gijax.sweep.consistency import common_mean_gains

Array = jax.Array


@dataclasses.dataclass(frozen=True)
class RTSSConfig:
    """Settings of the sphere-sweep baseline (hashable; static under ``jit``).

    Attributes:
      name: label.
      candidates: 'ev' (even in inverse distance) or 'gi' (geometry-informed, rig-aware); used
        by :func:`preset_candidates` (``rtss_predict`` takes the list itself).
      num_candidates: candidate count for :func:`preset_candidates`.
      d_min, d_max: candidate range, metres.
      match_view: 'fisheye' (each camera's own lens, resized) or 'equirect' (hemisphere).
      match_size: width of the matching images, pixels (512 in the paper's runs).
      references: indices of the reference cameras, or None for every camera.
      min_displacement: pixels; a partner camera must move the point by more than this
        between the nearest and the farthest candidate.
      cost: 'zncc' (default; zero-mean normalised cross-correlation of ``cost_window``-wide
        patches, cost ``0.5 (1 - ncc)``) or 'ad' (the original RTSS cost: sum of the 3
        absolute RGB differences of single pixels). 'ad' with ``normalize_gain`` is the
        paper's configuration.
      cost_window: patch width in pixels of the 'zncc' cost (odd).
      cost_clamp: upper bound of the per-pixel cost; also the cost of candidates the partner
        cannot see. 0.5 means "uncorrelated or worse" for 'zncc'.
      filter_levels: pyramid levels of the cost filter (0 = no filtering).
      filter_sigma: colour scale of the filter's edge weights.
      filter_alpha: share of the coarser level in every up-blend of the pyramid.
      stitch_samples: march steps when resampling a reference map to the panorama.
      fill_iterations: 3x3 hole-filling passes on the panorama.
      normalize_gain: scale each camera's matching view per channel so that its mean colour
        over valid pixels equals the mean over all cameras (cameras with different gain or
        white balance would otherwise never match under an absolute-difference cost).
    """

    name: str = "RS-E32"
    candidates: str = "ev"
    num_candidates: int = 32
    d_min: float = 0.5
    d_max: float = 100.0
    match_view: str = "fisheye"
    match_size: int = 512
    references: Optional[tuple] = None
    min_displacement: float = 1.0
    cost: str = "zncc"
    cost_window: int = 7
    cost_clamp: float = 0.5
    filter_levels: int = 5
    filter_sigma: float = 0.1
    filter_alpha: float = 0.5
    stitch_samples: int = 96
    fill_iterations: int = 2
    normalize_gain: bool = True

    def __post_init__(self):
        if self.candidates not in ("ev", "gi"):
            raise bad_field("RTSSConfig", "candidates", "'ev' or 'gi'", self.candidates)
        if self.num_candidates < 3:
            raise bad_field("RTSSConfig", "num_candidates", ">= 3", self.num_candidates)
        if not 0 < self.d_min < self.d_max:
            raise bad_field("RTSSConfig", "d_min", f"in (0, d_max = {self.d_max})", self.d_min)
        if self.cost not in COST_KINDS:
            raise bad_field("RTSSConfig", "cost", f"one of {COST_KINDS}", self.cost)
        if self.cost_window < 1 or self.cost_window % 2 == 0:
            raise bad_field("RTSSConfig", "cost_window", "a positive odd number of pixels",
                            self.cost_window)
        if self.stitch_samples < 2:
            raise ValueError(f"RTSSConfig.stitch_samples must be >= 2; found {self.stitch_samples}")
        MatchView(self.match_view, self.match_size)

    def replace(self, **kw) -> "RTSSConfig":
        return dataclasses.replace(self, **kw)


RTSS_PRESETS: dict[str, RTSSConfig] = {
    name: RTSSConfig(name=name, candidates=kind, num_candidates=n)
    for name, kind, n in (("RS-E16", "ev", 16), ("RS-G16", "gi", 16), ("RS-E32", "ev", 32),
                          ("RS-G32", "gi", 32))
}
# The paper's own configuration: RS-E32 with the original 1x1 absolute-difference cost.
RTSS_PRESETS["RS-E32-AD"] = RTSS_PRESETS["RS-E32"].replace(name="RS-E32-AD", cost="ad",
                                                           cost_window=1)


def get_rtss_preset(name: str) -> RTSSConfig:
    """A preset by name (RS-E16, RS-G16, RS-E32, RS-G32; RS-E32-AD = RS-E32 with the paper's
    1x1 absolute-difference cost); a lookup of static settings, nothing to trace."""
    if name not in RTSS_PRESETS:
        raise ValueError(f"unknown RTSS preset {name!r}; expected one of {sorted(RTSS_PRESETS)}")
    return RTSS_PRESETS[name]


def preset_candidates(rig: Rig, config: RTSSConfig) -> Array:
    """The candidate list (D,) metres of a configuration: EV, or GI derived from the rig (in the
    default float dtype; traceable in the rig like :func:`gijax.candidates.rig_gi_candidates`)."""
    from gijax import candidates as cand_lib

    kind = "ev" if config.candidates == "ev" else "gi"
    return cand_lib.candidates_for(kind, config.num_candidates, rig=rig, d_min=config.d_min,
                                   d_max=config.d_max)


def choose_candidates(spec: str | None, rig: Rig, config: RTSSConfig) -> tuple[np.ndarray, str]:
    """``(candidates (D,) float64 metres, description)`` for a command line's ``--candidates``.

    The baseline has no training list: without a spec (or with 'train') it runs its preset's
    own list; any other spec goes through :func:`gijax.candidates.spec.resolve_candidates`, and
    since the baseline's candidate count is free, a file of any length is taken as it is. Eager
    (it may read a file)."""
    from gijax.candidates.spec import resolve_candidates

    if spec in (None, "train"):
        kind = "even in inverse distance" if config.candidates == "ev" else "GI for the rig"
        return (np.asarray(preset_candidates(rig, config), np.float64),
                f"{config.name}'s own list ({config.num_candidates} {kind}, "
                f"{config.d_min:g}-{config.d_max:g} m)")
    return resolve_candidates(spec, rig, config.num_candidates, config.d_min, config.d_max,
                              any_count=True)


def _check_inputs(rig: Rig, images, masks, candidates, config: RTSSConfig):
    # Shapes raise in every regime; candidate values raise when concrete and are a checkify
    # debug check under a trace.
    n = rig.num_cameras
    if images.ndim != 4 or images.shape[0] != n or images.shape[-1] != 3:
        raise ValueError(f"images must have shape (Ncam={n}, h, w, 3); found {tuple(images.shape)}")
    for i, cam in enumerate(rig.cameras):
        if images.shape[1:3] != (cam.height, cam.width):
            raise ValueError(f"images: camera {i} is {cam.height}x{cam.width} in the rig but the "
                             f"images are {images.shape[1]}x{images.shape[2]}")
    if masks is not None and tuple(masks.shape) != tuple(images.shape[:3]):
        raise ValueError(f"masks must have shape {tuple(images.shape[:3])}; "
                         f"found {tuple(masks.shape)}")
    guard_candidates(candidates, min_count=3)
    refs = tuple(range(n)) if config.references is None else tuple(config.references)
    if not refs or any(not 0 <= r < n for r in refs):
        raise ValueError(f"RTSSConfig.references {config.references} must name cameras 0..{n - 1}")
    return refs


def _normalize_gain(view_images, view_masks):
    """Per-camera, per-channel gain so every view's valid mean colour equals the common mean."""
    means = [jnp.sum(im * m[..., None], (0, 1)) / jnp.maximum(jnp.sum(m), 1.0)
             for im, m in zip(view_images, view_masks)]
    gains = common_mean_gains(jnp.stack(means))
    return [jnp.clip(im * g, 0.0, 1.0) for im, g in zip(view_images, gains)]


def _stack_padded(arrays):
    """Stack arrays of possibly different (H, W, ...) shapes, zero-padding to the largest."""
    h = max(a.shape[0] for a in arrays)
    w = max(a.shape[1] for a in arrays)
    pad = [jnp.pad(a, [(0, h - a.shape[0]), (0, w - a.shape[1])] + [(0, 0)] * (a.ndim - 2))
           for a in arrays]
    return jnp.stack(pad)


def _gather_partner(stack: Array, sizes, partner: Array, coords: Array, valid: Array) -> Array:
    """Bilinear samples (D, H, W, 3) of each pixel's partner image from the stacked views.

    The stacked views (N, Hm, Wm, 3) are laid one below the other in one tall image; the
    coordinates are clamped inside the partner's own image before being offset, so the
    4-neighbour gather never reads a neighbouring camera's pixels.
    """
    n, hm, wm, c = stack.shape
    heights = jnp.asarray([s[0] for s in sizes], coords.dtype)[partner]
    widths = jnp.asarray([s[1] for s in sizes], coords.dtype)[partner]
    u = jnp.clip(coords[..., 0], 0.0, widths - 1.0)
    v = jnp.clip(coords[..., 1], 0.0, heights - 1.0) + partner.astype(coords.dtype) * hm
    tall = stack.reshape(n * hm, wm, c)
    warped, _ = bilinear_sample(tall, jnp.stack([u, v], -1), valid)
    return warped


def reference_map(rig: Rig, view: MatchView, ref, view_images, view_masks, sizes,
                  candidates: Array, config: RTSSConfig) -> dict:
    """One reference camera: its matching-view inverse-distance map and companions (H, W).

    ``ref`` is a camera index (traced when all cameras share model and size).
    """
    sel = select_best_camera(rig, view, ref, candidates, view_masks, config.min_displacement)
    coords, ok = sweep_coords(rig, view, ref, candidates, sel["best"], view_masks)
    stack = _stack_padded(view_images)
    warped = _gather_partner(stack, sizes, sel["best"], coords, ok)
    ref_img = item_at(view_images, ref)
    cost = matching_cost(config.cost, ref_img, warped, ok, config.cost_clamp, config.cost_window)
    conf = sel["valid"].astype(cost.dtype)
    cost = edge_aware_filter(cost, conf, ref_img, config.filter_levels, config.filter_sigma,
                             config.filter_alpha)
    wta = winner_take_all(cost, candidates)
    return dict(inv_distance=wta["inv_distance"], valid=sel["valid"],
                displacement=sel["displacement"], best=sel["best"], image=ref_img)


@functools.partial(jax.jit, static_argnames=("pano", "config"))
def sphere_sweep(rig: Rig, images: Array, masks: Array, candidates: Array, pano: Panorama,
                 config: RTSSConfig) -> dict:
    """The compiled sphere-sweep pipeline behind :func:`rtss_predict` (jitted; ``pano`` and
    ``config`` static), for callers that lower or compose it themselves.

    ``images`` (Ncam, h, w, 3) float in [0, 1], ``masks`` (Ncam, h, w) float (1 = valid),
    ``candidates`` (D,) ascending metres. Returns the dict of :func:`rtss_predict` with
    ``views`` always included. Shapes are checked when traced; values are not (see
    :func:`rtss_predict`).
    """
    refs = _check_inputs(rig, images, masks, candidates, config)
    view = MatchView(config.match_view, config.match_size)
    images = images.astype(jnp.float32)
    candidates = candidates.astype(jnp.float32)
    masks = masks.astype(jnp.float32)
    if is_homogeneous(rig):
        stacked = map_cameras(lambda cam, r, t, m, img, msk: view_image(view, cam, img, msk),
                              rig, images, masks)
        view_images, view_masks = list(stacked[0]), list(stacked[1])
    else:
        views = [view_image(view, rig.cameras[i], images[i], masks[i])
                 for i in range(rig.num_cameras)]
        view_images = [v[0] for v in views]
        view_masks = [v[1] for v in views]
    if config.normalize_gain:
        view_images = _normalize_gain(view_images, view_masks)
    sizes = [v.shape[:2] for v in view_images]
    if is_homogeneous(rig) and len(set(sizes)) == 1:
        # One compiled body mapped over the reference cameras (compile time and memory do
        # not grow with the number of references).
        maps = jax.lax.map(lambda r: reference_map(rig, view, r, view_images, view_masks, sizes,
                                                   candidates, config),
                           jnp.asarray(refs, jnp.int32))
    else:
        per_ref = [reference_map(rig, view, r, view_images, view_masks, sizes, candidates,
                                 config) for r in refs]
        maps = {k: [m[k] for m in per_ref] for k in per_ref[0]}
    out = stitch(rig, view, refs, maps["inv_distance"], maps["valid"], maps["displacement"],
                 masks, candidates, pano, config.stitch_samples, config.fill_iterations)
    inv = out["inv_distance"]
    return dict(inv_distance=inv, distance=1.0 / inv, valid=out["valid"],
                visible=out["visible"], views=maps)



def rtss_predict(rig: Rig, images, masks, candidates, pano: Panorama = Panorama.hemisphere(160, 640),
                 config: RTSSConfig = RTSSConfig(), return_views: bool = False) -> dict:
    """Sphere-sweep stereo for any rig, camera models and candidate list.

    Args:
      rig: the camera rig (its camera sizes must match the images).
      images: (Ncam, h, w, 3) float RGB in [0, 1] (uint8 is divided by 255).
      masks: (Ncam, h, w), 1 = valid pixel, or None for the rig's own masks.
      candidates: (D,) ascending distances, metres.
      pano: output panorama (static).
      config: :class:`RTSSConfig` (static).
      return_views: also return the per-reference-camera maps under ``views``: a dict of
        ``inv_distance``, ``valid``, ``displacement`` (pixels), ``best`` (partner camera) and
        ``image`` (matching view), each stacked over the reference cameras when all cameras
        share model and size, else a list per reference camera.

    Returns dict of jax arrays over the panorama (Hp, Wp): ``inv_distance`` (1/m) and
    ``distance`` (m), both NaN where ``valid`` is False; ``valid`` (bool); ``visible`` (bool,
    some pair of cameras sees the ray at some candidate distance).

    Traceable (jit, vmap over images and masks, grad in the images where the winner and its
    neighbours do not switch): shapes raise ValueError in every case; the candidate list is
    checked (:func:`gijax.candidates.check_candidates`) when concrete and by a checkify debug
    check when traced.
    """
    images = jnp.asarray(images)
    _check_inputs(rig, images, masks, jnp.asarray(candidates), config)
    if images.dtype == jnp.uint8:
        images = images.astype(jnp.float32) / 255.0
    if masks is None:
        # Resolved here rather than inside the compiled function, so that calls with and
        # without explicit masks share one compilation.
        masks = jnp.stack([jnp.ones((c.height, c.width), jnp.float32) if m is None
                           else jnp.asarray(m, jnp.float32)
                           for c, m in zip(rig.cameras, rig.masks)])
        if masks.shape != images.shape[:3]:
            raise ValueError(f"images have shape {tuple(images.shape)} but the rig's cameras "
                             f"and masks are {tuple(masks.shape)}")
    masks = jnp.asarray(masks, jnp.float32)
    out = sphere_sweep(rig, images, masks, jnp.asarray(candidates), pano, config)
    if not return_views:
        out.pop("views")
    return out


def rtss_predict_sample(rig: Rig, sample: dict, preset_name: str = "RS-E32",
                        candidates=None, pano: Panorama | None = None, **overrides) -> dict:
    """Run a preset on one rendered or loaded sample (a dict like ``render_sample``'s output).

    ``sample`` holds ``images`` (Ncam, h, w, 3) uint8 or float, optionally ``masks`` and
    ``pano_distance`` (Hp, Wp), whose shape sets the output panorama when ``pano`` is None
    (hemisphere; 160 x 640 when absent). The panorama is oriented by the rig's panorama frame. The matching size defaults to the smaller of the preset's size and the
    cameras' image width. ``overrides`` replace preset fields; ``candidates`` replaces the
    preset's list. Returns numpy arrays (see :func:`rtss_predict`): an eager edge, not traced.
    """
    config = get_rtss_preset(preset_name)
    if "images" not in sample:
        raise ValueError("sample has no 'images' entry")
    if "match_size" not in overrides:
        overrides["match_size"] = min(config.match_size, min(c.width for c in rig.cameras))
    config = config.replace(**overrides)
    if candidates is None:
        candidates = preset_candidates(rig, config)
    if pano is None:
        shape = np.shape(sample["pano_distance"]) if "pano_distance" in sample else (160, 640)
        pano = Panorama.hemisphere(int(shape[0]), int(shape[1]))
    masks = sample.get("masks")
    out = rtss_predict(rig, sample["images"], masks, candidates, pano, config)
    return {k: np.asarray(v) for k, v in out.items()}
