"""The whole network: surrogate images -> shared features -> sphere sweep -> cost volume -> 3D
U-Net -> soft-argmax in inverse distance.

One call runs the network anywhere in gijax (training, evaluation, adaptation, predict, the
ONNX export, the benchmarks): ``model(surrogates, masks, grids)``, :class:`OmniStereoNet` on
surrogate images with the :class:`gijax.sweep.grids.SweepGrids` of the rig and candidates.
:func:`model_grids` (config, rig, candidates, output panorama) makes those grids: it turns the
config into the sizes the sweep layer takes. Raw fisheye images become surrogate images first,
by :func:`gijax.sweep.grids.fisheye_surrogates` with the
:func:`gijax.sweep.grids.surrogate_resampling` maps at ``config.surrogate_hw`` (the data
loader does the same per sample on its own threads); :func:`on_fisheye_images` is that step
and the call together, for the paths that start from raw images (predict, the experiments'
timed evaluations, the ONNX export). The network's stages are its methods
(:meth:`OmniStereoNet.extract_features`, :meth:`~OmniStereoNet.sweep`,
:meth:`~OmniStereoNet.matching`, :meth:`~OmniStereoNet.build_cost_volume`, :meth:`~OmniStereoNet.unet_logits`,
:meth:`~OmniStereoNet.regress`, :meth:`~OmniStereoNet.refined`), which ``__call__`` runs in
order.

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
import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from gijax.geometry.panorama import Panorama
from gijax.geometry.panorama_frame import coverage_of, panorama_of
from gijax.geometry.rig import Rig
from gijax.nn import (Conv3D, FeatureExtractor, ModelConfig, get_preset, make_cost_volume,
                      make_matching_skip, make_unet, param_count, regress)
from gijax.nn.refine import GuidedRefinement, colour_guide
from gijax.sweep.grids import (SurrogateMaps, SweepGrids, cost_panorama, fisheye_surrogates,
                               match_grey, sweep_colours, sweep_features, sweep_grids)
from gijax.sweep.matching import cell_zncc_batch_last

Array = jax.Array

# The network's stages, in the order ``OmniStereoNet.__call__`` runs them; each one's operations
# carry its name in their JAX name stack (``jax.named_scope``), so that XLA's profile of a
# compiled step (``benchmarks/bench_step_profile.py``) can say which stage an instruction
# belongs to, forward or backward.
STAGES = ("extract_features", "sweep", "matching", "build_cost_volume", "unet_logits",
          "regress", "refined")


def _stage(method):
    """Run ``method`` under a name scope of its own name (one of :data:`STAGES`)."""
    if method.__name__ not in STAGES:
        raise ValueError(f"{method.__name__} is not one of the network's stages {STAGES}")

    @functools.wraps(method)
    def scoped(self, *args, **kwargs):
        with jax.named_scope(method.__name__):
            return method(self, *args, **kwargs)
    return scoped


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


def _check_output_panorama(config: ModelConfig, pano: Panorama) -> None:
    h, w = pano.shape
    m = 8 * config.output_stride
    if h % m or w % m:
        part = "half the output" if config.output_stride == 2 else "the output's size"
        raise ValueError(f"model {config.name!r}: an output panorama of {h} x {w} cannot run; "
                         f"both sides must be divisible by {m} (the cost volume is {part} "
                         f"and the U-Net halves it three times)")


def model_grids(config: ModelConfig, rig: Rig, candidates: Array,
                pano: Panorama | None = None) -> SweepGrids:
    """The :class:`~gijax.sweep.grids.SweepGrids` of a network of ``config`` for ``rig`` (at the
    model's image size, i.e. intrinsics already scaled by ``config.image_scale``),
    ``candidates`` (D,) metres and the output panorama ``pano`` (static; default
    :func:`model_panorama`, the coverage the model was trained on): the sweep over its cost
    panorama into the feature maps, the guide grids when ``config.refine`` and the match grids
    with a matching cost. Pure and traceable: evaluated once for a fixed rig, or inside jit
    when the rig is an input."""
    check_model_candidates(config, candidates)
    pano = model_panorama(config) if pano is None else pano
    _check_output_panorama(config, pano)
    samples = config.matching_samples if config.matching_cost != "none" else 0
    return sweep_grids(rig, candidates, cost_panorama(pano, config.output_stride),
                       config.feature_hw, pano if config.refine else None,
                       config.surrogate_hw if (config.refine or samples) else None,
                       match_samples=samples)


def coverage_note(config: ModelConfig, pano: Panorama) -> str | None:
    """A warning when ``pano`` covers another part of the sphere than ``config`` was trained
    on (the network then sees latitudes it never saw), else None."""
    asked = coverage_of(pano)
    if asked == config.panorama:
        return None
    return (f"warning: model {config.name!r} was trained on the {config.panorama}; it is run "
            f"on the {asked} here, whose other latitudes it has never seen")


def check_model_candidates(config: ModelConfig, candidates) -> None:
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


class OmniStereoNet(nnx.Module):
    """Omnidirectional stereo from N per-camera surrogate images (see the module docstring)."""

    def __init__(self, config: ModelConfig, rngs: nnx.Rngs):
        self.config = config
        self.features = FeatureExtractor(config, rngs)
        self.cost_volume = make_cost_volume(config, rngs)
        self.unet = make_unet(config, rngs)
        self.matching_skip = make_matching_skip(config, rngs)
        self.refine = GuidedRefinement(config.num_candidates, rngs) if config.refine else None

    def __call__(self, surrogates: Array, masks: Array, grids: SweepGrids) -> dict:
        """The network from surrogate images (B, N, Hs, Ws, 3) in [0, 1], their masks
        (B, N, Hm, Wm) and the sweep grids of the rig and candidates (:func:`model_grids`).

        Returns ``inv_distance`` (B, H, W) 1/m, ``distance`` (B, H, W) m, ``prob``
        (B, D, H, W), ``entropy`` (B, H, W) nats, ``logits`` (B, D, h, w) (the U-Net output)
        and ``valid`` (B, H, W) bool: the cell is seen by at least two cameras (variance) or by
        every camera (concat) at every candidate; with the guided refinement also
        ``inv_distance_coarse``, the soft-argmax estimate before it. The model must be in the
        mode wanted (eval for inference).
        """
        cfg = self.config
        check_surrogates(cfg, surrogates, masks, grids.sweep_px.shape[0])
        n = surrogates.shape[1]
        dtype = surrogates.dtype
        feats = self.extract_features(surrogates)
        sampled, cam_valid = self.sweep(feats, masks, grids)
        matching = (self.matching(surrogates, masks, grids)
                    if cfg.matching_cost != "none" else None)
        logits = self.unet_logits(self.build_cost_volume(sampled, cam_valid, matching), matching)
        out = self.regress(logits, grids.candidates.astype(dtype))
        if cfg.refine:
            out.update(self.refined(surrogates, masks, grids, out))
        needed = 2 if cfg.cost_volume == "variance" else n
        # Float reductions: TensorRT reduces float tensors only (no integer / boolean ReduceSum).
        seen_by = jnp.min(jnp.sum(cam_valid.astype(dtype), axis=1), axis=1)   # (B, h, w)
        cell_ok = seen_by >= needed
        k = cfg.output_stride
        out["valid"] = jnp.repeat(jnp.repeat(cell_ok, k, axis=1), k, axis=2)
        return out

    @_stage
    def extract_features(self, surrogates: Array) -> Array:
        """Surrogate images (B, N, Hs, Ws, 3) -> features (B, N, Hs/4, Ws/4, C), one extractor
        shared by all cameras."""
        b, n, hs, ws, _ = surrogates.shape
        feats = self.features(surrogates.reshape(b * n, hs, ws, 3))
        return feats.reshape(b, n, *feats.shape[1:])

    @_stage
    def sweep(self, features: Array, masks: Array, grids: SweepGrids) -> tuple[Array, Array]:
        """Features (B, N, hf, wf, C) and masks (B, N, Hm, Wm) at the sweep grids by
        ``config.sweep_boundary``: (B, N, D, h, w, C) and the per-camera validity
        (B, N, D, h, w) bool (:func:`gijax.sweep.grids.sweep_features`)."""
        return sweep_features(features, masks, grids, self.config.sweep_boundary)

    @_stage
    def matching(self, surrogates: Array, masks: Array, grids: SweepGrids) -> Array:
        """The matching-cost channel (B, D, h, w, 1): the cameras' agreement per candidate and
        cost cell (:func:`gijax.sweep.matching.cell_zncc_batch_last` of the grey levels at the
        match grids). No weights: a cue computed from the images, not learned."""
        cfg = self.config
        if cfg.matching_cost == "none":
            raise ValueError(f"model {cfg.name!r} has no matching cost")
        if grids.match_px is None:
            raise ValueError(f"model {cfg.name!r} has a matching cost and needs the match "
                             f"grids in its sweep grids (gijax.model.model_grids)")
        grey, seen = match_grey(surrogates, masks, grids, cfg.sweep_boundary, batch_last=True)
        ncc = cell_zncc_batch_last(grey, seen, cfg.matching_samples)    # (D, h, w, B)
        return jnp.moveaxis(ncc, -1, 0)[..., None]

    @_stage
    def build_cost_volume(self, sampled: Array, valid: Array,
                          matching: Array | None = None) -> Array:
        """Swept features (B, N, D, h, w, C), their validity (B, N, D, h, w) and, for a model
        with a matching cost, its channel (B, D, h, w, 1) -> the cost volume
        (B, D, h, w, unet_in)."""
        return self.cost_volume(sampled, valid.astype(sampled.dtype), matching)

    @_stage
    def unet_logits(self, volume: Array, matching: Array | None = None) -> Array:
        """The cost volume (B, D, h, w, unet_in) -> the logits (B, D, h, w): the U-Net's, plus
        the matching cost's skip (B, D, h, w, 1 -> :mod:`gijax.nn.matching_skip`) for a model
        built with ``matching_skip``."""
        logits = self.unet(volume)
        if self.matching_skip is None:
            return logits
        if matching is None:
            raise ValueError(f"model {self.config.name!r} adds its matching cost to the "
                             f"logits (matching_skip) and needs it here")
        return logits + self.matching_skip(matching).astype(logits.dtype)

    @_stage
    def regress(self, logits: Array, candidates: Array) -> dict:
        """Logits (B, D, h, w) and candidates (D,) metres -> the regressed outputs at
        ``output_stride`` x the cost grid (whichever panorama it covers; the estimate the
        configuration's ``estimate`` names, :mod:`gijax.nn.regressor`): ``inv_distance``,
        ``distance``, ``prob``, ``entropy`` and the ``logits`` themselves."""
        k = self.config.output_stride
        h, w = logits.shape[2:4]
        out = dict(regress(logits, candidates.astype(logits.dtype), (k * h, k * w),
                           self.config.estimate, self.config.mode_window,
                           self.config.mode_pick))
        out["logits"] = logits
        return out

    @_stage
    def refined(self, surrogates: Array, masks: Array, grids: SweepGrids, out: dict) -> dict:
        """The guided refinement of the soft-argmax outputs ``out`` (:meth:`regress`), from the
        cameras' colours at the guide grids: ``inv_distance`` and ``distance`` refined, the
        soft-argmax estimate kept as ``inv_distance_coarse``."""
        if self.refine is None:
            raise ValueError(f"model {self.config.name!r} has no guided refinement")
        if grids.guide_px is None:
            raise ValueError(f"model {self.config.name!r} refines its estimate and needs the "
                             f"guide grids in its sweep grids (gijax.model.model_grids)")
        dtype = surrogates.dtype
        colours, seen = sweep_colours(surrogates, masks, grids, self.config.sweep_boundary)
        prob = jax.lax.stop_gradient(out["prob"])
        guide = colour_guide(colours, seen, prob)
        cand = grids.candidates.astype(dtype)
        coarse = jax.lax.stop_gradient(out["inv_distance"])
        inv = self.refine(coarse, jax.lax.stop_gradient(out["entropy"]), guide,
                          (1.0 / cand[-1], 1.0 / cand[0]))
        return {"inv_distance": inv, "distance": 1.0 / inv,
                "inv_distance_coarse": out["inv_distance"]}


def on_fisheye_images(model: OmniStereoNet, images: Array, masks: Array, maps: SurrogateMaps,
                      grids: SweepGrids) -> dict:
    """The network on raw fisheye images (B, N, h, w, 3) float in [0, 1] and their masks
    (B, N, h, w): their surrogate images by ``maps``
    (:func:`gijax.sweep.grids.surrogate_resampling` of the rig at ``config.surrogate_hw``),
    then ``model(surrogates, masks, grids)``. Traceable; returns the network's outputs."""
    surrogates, sur_masks = fisheye_surrogates(maps, images, masks)
    return model(surrogates, sur_masks, grids)


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


def reconfigured(model: OmniStereoNet, **changes) -> OmniStereoNet:
    """``model``'s weights and BatchNorm statistics under its configuration with ``changes``,
    which may only touch fields that change no weight
    (:data:`gijax.nn.presets.WEIGHTLESS_FIELDS`: e.g. ``estimate='mode'`` reads a network by
    its sub-pixel mode); a new module in eval mode, ``model`` unchanged. Nothing is initialised
    (the new module's structure is built abstractly, then takes ``model``'s state)."""
    from gijax.nn.presets import WEIGHTLESS_FIELDS

    other = sorted(set(changes) - WEIGHTLESS_FIELDS)
    if other:
        raise ValueError(f"reconfigured: {', '.join(other)} change(s) the weights; only "
                         f"{', '.join(sorted(WEIGHTLESS_FIELDS))} may change")
    config = dataclasses.replace(model.config, **changes)
    new = nnx.eval_shape(lambda: OmniStereoNet(config, nnx.Rngs(0)))
    nnx.update(new, nnx.state(model))
    new.eval()
    return new


def with_estimate(model: OmniStereoNet, estimate: str | None,
                  mode_pick: int | None = None) -> OmniStereoNet:
    """``model`` read by ``estimate`` ('mean' or 'mode', :mod:`gijax.nn.regressor`) and, for
    the mode, ``mode_pick`` (None or its own: unchanged; neither changed: ``model`` itself), as
    ``--estimate`` asks (:func:`reconfigured`)."""
    changes = {k: v for k, v in (("estimate", estimate), ("mode_pick", mode_pick))
               if v is not None and v != getattr(model.config, k)}
    return reconfigured(model, **changes) if changes else model


def count_parameters(config: ModelConfig | str) -> dict[str, int]:
    """Trainable parameter counts {'features', 'cost', 'unet', 'total'} of the
    :class:`OmniStereoNet` of a config or preset name (its feature extractor, cost-volume
    builder and U-Net; the sweep and the regressor have none), from abstract shapes only (no
    memory, no compilation)."""
    if isinstance(config, str):
        config = get_preset(config)
    # Only the layer structure matters: presets differing in candidates, loss or sizes share it.
    structural = dataclasses.replace(
        config, name="", candidates="ev", loss="volume", mask_augmentation=False,
        num_candidates=8, surrogate_hw=(32, 32), cost_hw=(8, 8), output_hw=(16, 16),
        image_scale=1.0, d_min=0.5, d_max=100.0, conv3d="auto", refine=False, output_stride=2,
    )
    return dict(_count(structural))


@functools.lru_cache(maxsize=32)
def _count(config: ModelConfig) -> tuple[tuple[str, int], ...]:
    model = nnx.eval_shape(lambda: OmniStereoNet(config, nnx.Rngs(0)))
    counts = {
        "features": param_count(model.features),
        "cost": param_count(model.cost_volume),
        # The matching skip's 27 weights count with the U-Net, whose logits they add to.
        "unet": param_count(model.unet) + (param_count(model.matching_skip)
                                           if model.matching_skip is not None else 0),
    }
    counts["total"] = sum(counts.values())
    return tuple(counts.items())


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
