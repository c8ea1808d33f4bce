"""The inference graph that is exported: raw fisheye images -> inverse distance panorama.

One pure function, :func:`forward_from_grids`, runs the whole network from *sampling grids*:

1. surrogate resampling: each raw fisheye image and its mask are sampled at the surrogate grid
   (per camera, the fisheye pixel of every surrogate hemisphere pixel; bilinear 4-neighbour
   gather), colours zeroed where the resampled mask is at most 0.5;
2. the shared feature extractor;
3. the sphere sweep: features and surrogate masks sampled at the sweep grid (longitude wraps);
4. the cost volume, the 3-D U-Net and the soft-argmax regressor.

The grids come from :func:`inference_grids`, which is evaluated either once, eagerly, to bake
them into the exported file as constants (a fixed rig: the engine only gathers), or inside the
exported function from rig inputs (intrinsics, poses, reference point and candidates are then
graph inputs). Both paths compute exactly what :class:`gijax.model.OmniStereoNet` computes from
surrogate images made by :func:`gijax.sweep.surrogate.surrogate_images`.

Shapes: B samples, N cameras, raw images (h, w) at the model's image size (the calibrated size
times ``config.image_scale``), surrogates (Hs, Ws), D candidates, cost volume (hc, wc), output
(H, W) = 2 (hc, wc).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from gijax.geometry import cameras as cam_lib
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import Rig, is_homogeneous, map_cameras
from gijax.model import MASK_THRESHOLD, OmniStereoNet
from gijax.nn import regress
from gijax.nn.presets import ModelConfig
from gijax.sampling import bilinear_sample
from gijax.sweep.grid import feature_to_surrogate, sweep_grid
from gijax.sweep.sample import sample_sweep
from gijax.sweep.surrogate import surrogate_grid

Array = jax.Array


@dataclasses.dataclass(frozen=True)
class Grids:
    """Sampling grids of one rig and candidate list (a pytree of arrays).

    Attributes:
      surrogate_px: (N, Hs, Ws, 2) raw-image pixel (u, v) of every surrogate pixel.
      surrogate_ok: (N, Hs, Ws) bool, the surrogate pixel is inside the lens image.
      sweep_px: (N, D, hc, wc, 2) feature-map pixel of every (candidate, cell) per camera.
      sweep_ok: (N, D, hc, wc) bool, the point is in front of and seen by that camera.
    """

    surrogate_px: Array
    surrogate_ok: Array
    sweep_px: Array
    sweep_ok: Array


jax.tree_util.register_dataclass(
    Grids, data_fields=["surrogate_px", "surrogate_ok", "sweep_px", "sweep_ok"], meta_fields=[])


def inference_grids(rig: Rig, candidates: Array, config: ModelConfig) -> Grids:
    """The sampling grids of ``rig`` (at the model's image size) and ``candidates`` (D,) metres."""
    sur_pano = Panorama.hemisphere(*config.surrogate_hw)

    def one(cam, _rot, _trans, _mask):
        return surrogate_grid(cam, sur_pano)

    sur_px, sur_ok = map_cameras(one, rig)
    coords, ok = sweep_grid(rig, candidates, Panorama.hemisphere(*config.cost_hw),
                            Panorama.hemisphere(*config.feature_hw))
    return Grids(sur_px, sur_ok, coords, ok)


def _fold_batch(x: Array) -> Array:
    """(B, N, H, W, C) -> (N, H, W, B C): one gather per camera serves the whole batch."""
    b, n, h, w, c = x.shape
    return jnp.transpose(x, (1, 2, 3, 0, 4)).reshape(n, h, w, b * c)


def _unfold_batch(x: Array, b: int) -> Array:
    """(N, ..., B C) -> (B, N, ..., C)."""
    n, rest, bc = x.shape[0], x.shape[1:-1], x.shape[-1]
    x = x.reshape(n, *rest, b, bc // b)
    return jnp.moveaxis(x, -2, 0)


def forward_from_grids(model: OmniStereoNet, images: Array, masks: Array, grids: Grids,
                       candidates: Array) -> dict:
    """The network from raw images and precomputed (or traced) grids.

    Args:
      model: the network, already in eval mode.
      images: (B, N, h, w, 3) float32 RGB in [0, 1].
      masks: (B, N, h, w) float32, 1 = the pixel sees the world.
      grids: :class:`Grids` of the rig and candidates.
      candidates: (D,) ascending metres.

    Returns:
      dict of ``inv_distance`` (B, H, W) 1/m, ``distance`` (B, H, W) m, ``entropy`` (B, H, W)
      nats (uncertainty) and ``valid`` (B, H, W) float32 in {0, 1}.
    """
    cfg = model.config
    b, n = images.shape[0], images.shape[1]
    dtype = images.dtype
    # Surrogate images: colours and mask of all samples in one gather per camera.
    stacked = _fold_batch(jnp.concatenate([images, masks[..., None].astype(dtype)], axis=-1))
    sampled, inside = jax.vmap(bilinear_sample)(stacked, grids.surrogate_px.astype(dtype),
                                                grids.surrogate_ok)
    sampled = _unfold_batch(sampled, b)                         # (B, N, Hs, Ws, 4)
    sur_mask = sampled[..., 3] * inside[None].astype(dtype)
    surrogates = sampled[..., :3] * (sur_mask > 0.5)[..., None].astype(dtype)
    hs, ws = surrogates.shape[2:4]
    feats = model.features(surrogates.reshape(b * n, hs, ws, 3))
    feats = feats.reshape(b, n, *feats.shape[1:])                # (B, N, hf, wf, C)
    # Sweep: features at the sweep grid, surrogate masks at the same directions.
    feature_pano = Panorama.hemisphere(*feats.shape[2:4])
    coords = grids.sweep_px.astype(dtype)
    mask_coords = feature_to_surrogate(coords, feature_pano, Panorama.hemisphere(hs, ws))
    swept, ok = sample_sweep(_fold_batch(feats), coords, grids.sweep_ok)
    swept = _unfold_batch(swept, b)                              # (B, N, D, hc, wc, C)
    swept_mask, _ = sample_sweep(jnp.moveaxis(sur_mask, 0, -1), mask_coords, grids.sweep_ok)
    swept_mask = jnp.moveaxis(swept_mask, -1, 0)                 # (B, N, D, hc, wc)
    cam_valid = ok[None] & (swept_mask > MASK_THRESHOLD)
    volume = model.cost_volume(swept, cam_valid.astype(dtype))
    logits = model.unet(volume)
    out = regress(logits, candidates.astype(dtype), cfg.output_hw)
    needed = 2 if cfg.cost_volume == "variance" else n
    # Float reductions: TensorRT reduces float tensors only (no integer / boolean ReduceSum).
    seen_by = jnp.min(jnp.sum(cam_valid.astype(dtype), axis=1), axis=1)   # (B, hc, wc)
    cell_ok = seen_by >= needed
    fy, fx = cfg.output_hw[0] // cfg.cost_hw[0], cfg.output_hw[1] // cfg.cost_hw[1]
    valid = jnp.repeat(jnp.repeat(cell_ok, fy, axis=1), fx, axis=2)
    return {"inv_distance": out["inv_distance"], "distance": out["distance"],
            "entropy": out["entropy"], "valid": valid.astype(dtype)}


# ----------------------------------------------------------------------------- rig as inputs

def intrinsics_layout(rig: Rig) -> tuple[str, ...]:
    """Column names of the (N, P) intrinsics input: the model's parameters, then ``fov``
    (radians). ValueError when the cameras do not share one model and image size."""
    if not is_homogeneous(rig) and len({type(c) for c in rig.cameras}) != 1:
        models = sorted({c.MODEL for c in rig.cameras})
        raise ValueError(f"a rig exported with its intrinsics as inputs needs one camera model "
                         f"for all cameras; this rig mixes {models}")
    sizes = {(c.width, c.height) for c in rig.cameras}
    if len(sizes) != 1:
        raise ValueError(f"a rig exported with its intrinsics as inputs needs one image size for "
                         f"all cameras; found {sorted(sizes)} (width, height)")
    return (*rig.cameras[0].PARAMS, "fov")


def rig_arrays(rig: Rig) -> dict:
    """The rig as plain arrays: ``intrinsics`` (N, P) float32 in the order of
    :func:`intrinsics_layout`, ``rotations`` (N, 3, 3), ``translations`` (N, 3) metres,
    ``reference`` (3,) metres."""
    names = intrinsics_layout(rig)
    intr = jnp.stack([jnp.stack([jnp.asarray(getattr(c, k), jnp.float32) for k in names])
                      for c in rig.cameras])
    return {"intrinsics": intr, "rotations": jnp.asarray(rig.rotations, jnp.float32),
            "translations": jnp.asarray(rig.translations, jnp.float32),
            "reference": jnp.asarray(rig.reference, jnp.float32)}


def rig_from_arrays(template: Rig, intrinsics: Array, rotations: Array, translations: Array,
                    reference: Array) -> Rig:
    """``template`` with its intrinsics, poses and reference replaced (camera model, image size
    and names stay those of the template); traceable."""
    names = intrinsics_layout(template)
    cams = []
    for i, cam in enumerate(template.cameras):
        values = {k: intrinsics[i, j] for j, k in enumerate(names)}
        cams.append(dataclasses.replace(cam, **values))
    return template.replace(cameras=tuple(cams), rotations=rotations, translations=translations,
                            reference=reference, masks=tuple(None for _ in cams), occluder=None)


def check_camera_model(rig: Rig) -> None:
    """ValueError unless every camera's model is one gijax can project."""
    for i, cam in enumerate(rig.cameras):
        if type(cam) not in cam_lib.CAMERA_MODELS.values():
            raise ValueError(f"camera {i}: unsupported camera type {type(cam).__name__}")
