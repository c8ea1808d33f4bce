"""Inference: raw fisheye images -> distance panorama, and the files that show it.

:func:`predict` is pure (arrays in, arrays out): raw images are resampled to the model's
surrogate images and run through the network in eval mode (BatchNorm running statistics), both
by :func:`gijax.model.forward` with grids from :func:`gijax.model.make_grids`. :func:`write_prediction` writes the results: the
distance panorama as float32 ``.npy``, colour-mapped PNGs with colour bars (distance and
uncertainty), a coloured point cloud (``.ply``) and the per-pixel validity.

Invalid pixels (seen by fewer cameras than a distance needs: the model's ``valid`` output, or
RTSS's) follow one convention in every file, whichever method made them (:data:`INVALID`):
NaN in ``distance.npy``, False / 0 in ``valid.npy`` / ``valid.png``, black in the colour maps,
absent from ``points.ply``, and counted in ``prediction.json``. The in-memory result of
:func:`predict` keeps the network's raw values there, marked only by ``valid``.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from gijax.geometry.panorama import Panorama, ray_grid
from gijax.geometry.rig import Rig, project_rig_points, scale_rig
from gijax.io.paths import write_bytes_atomic
from gijax.model import OmniStereoNet, check_candidates, forward, make_grids
from gijax.nn.presets import ModelConfig
from gijax.sampling import bilinear_sample
from gijax.sweep.surrogate import as_float_image, check_images

Array = jax.Array


@nnx.jit
def _forward(model: OmniStereoNet, images, masks, rig, candidates):
    return forward(model, images, masks, make_grids(rig, candidates, model.config))


@jax.jit
def _point_colours(rig: Rig, images: Array, distance: Array) -> Array:
    """(H, W, 3) colour of each predicted point, from the camera closest to the reference that
    sees it (by projection validity and the rig's masks); 0 where no camera sees it."""
    pano = Panorama.hemisphere(*distance.shape)
    points = rig.reference + distance[..., None] * ray_grid(pano, distance.dtype)
    pixels, seen = project_rig_points(rig, points)
    colours, seen = jax.vmap(bilinear_sample)(images, pixels, seen)
    order = jnp.argsort(jnp.linalg.norm(rig.translations - rig.reference, axis=-1))
    out = jnp.zeros(distance.shape + (images.shape[-1],), images.dtype)
    filled = jnp.zeros(distance.shape, bool)
    for k in range(rig.num_cameras):  # static count; nearest camera first
        i = order[k]
        take = seen[i] & ~filled
        out = jnp.where(take[..., None], colours[i], out)
        filled = filled | take
    return out


def model_rig(config: ModelConfig, rig: Rig, image_hw: tuple[int, int]) -> tuple[Rig, bool]:
    """The rig matching images of size ``image_hw`` and whether the images must be resized.

    Images may come at the rig's own size (resized by ``config.image_scale`` when that is not 1)
    or already at the scaled size.
    """
    cam = rig.cameras[0]
    if image_hw == (cam.height, cam.width):
        if config.image_scale == 1.0:
            return rig, False
        return scale_rig(rig, config.image_scale), True
    if config.image_scale != 1.0:
        scaled = scale_rig(rig, config.image_scale)
        if image_hw == (scaled.cameras[0].height, scaled.cameras[0].width):
            return scaled, False
        raise ValueError(f"images must be {cam.height} x {cam.width} (the rig's size) or "
                         f"{scaled.cameras[0].height} x {scaled.cameras[0].width} (scaled by "
                         f"{config.image_scale} for model {config.name!r}); found "
                         f"{image_hw[0]} x {image_hw[1]}")
    raise ValueError(f"images must be {cam.height} x {cam.width} (the rig's size); found "
                     f"{image_hw[0]} x {image_hw[1]}")


def _resize(images: np.ndarray, rig: Rig, interpolation: int) -> np.ndarray:
    cam = rig.cameras[0]
    out = [cv2.resize(np.ascontiguousarray(im), (cam.width, cam.height),
                      interpolation=interpolation) for im in images]
    return np.stack([o.reshape(cam.height, cam.width, *im.shape[2:]) for o, im in
                     zip(out, images)])


def predict(model: OmniStereoNet, rig: Rig, images, masks, candidates) -> dict:
    """Distance panorama of one sample.

    Args:
      model: an :class:`OmniStereoNet` (its mode is not changed: eval mode is applied to a view).
      rig: the rig at its calibrated image size.
      images: (N, h, w, 3) raw fisheye images, uint8 or float RGB in [0, 1], at the rig's size
        or at the rig's size times ``model.config.image_scale``.
      masks: (N, h, w) validity masks (1 = sees the world) or None for the rig's own masks.
      candidates: (D,) ascending distances in metres, D = the model's candidate count.

    Returns:
      numpy dict: ``inv_distance`` (H, W) 1/m, ``distance`` (H, W) m, ``prob`` (D, H, W),
      ``entropy`` (H, W) nats, ``valid`` (H, W) bool, ``colour`` (H, W, 3) in [0, 1] (the
      image colour at each predicted point) and ``candidates`` (D,).
    """
    config = model.config
    images = np.asarray(images)
    if images.ndim != 4:
        raise ValueError(f"images must have shape (num_cameras, height, width, 3); found "
                         f"{images.shape}")
    if images.shape[0] != rig.num_cameras:
        raise ValueError(f"the rig has {rig.num_cameras} cameras but {images.shape[0]} images "
                         f"were given")
    if images.shape[-1] != 3:
        raise ValueError(f"images must have 3 (RGB) channels; found {images.shape[-1]}")
    check_candidates(config, candidates)
    if config.cost_volume == "concat" and rig.num_cameras != config.num_cameras:
        raise ValueError(f"model {config.name!r} concatenates exactly {config.num_cameras} cameras;"
                         f" the rig has {rig.num_cameras}")
    run_rig, resize = model_rig(config, rig, tuple(images.shape[1:3]))
    if masks is not None:
        masks = np.asarray(masks)
        if masks.shape != images.shape[:3]:
            raise ValueError(f"masks must have shape {images.shape[:3]} to match the images; "
                             f"found {masks.shape}")
    if resize:
        images = _resize(images, run_rig, cv2.INTER_AREA)
        if masks is not None:
            masks = _resize(masks.astype(np.float32), run_rig, cv2.INTER_AREA)
    check_images(run_rig, images, masks)
    images = as_float_image(images)
    if masks is None:
        masks = np.stack([np.ones((c.height, c.width), np.float32) if m is None else np.asarray(m)
                          for c, m in zip(run_rig.cameras, run_rig.masks)])
    graphdef, state = nnx.split(model)
    view = nnx.merge(graphdef, state)
    view.eval()
    cand = jnp.asarray(candidates, jnp.float32)
    out = _forward(view, images[None], jnp.asarray(masks, jnp.float32)[None], run_rig, cand)
    result = {k: np.asarray(v[0]) for k, v in out.items()}
    colour_rig = run_rig if masks is None else run_rig.replace(
        masks=tuple(jnp.asarray(m, jnp.float32) for m in masks))
    result["colour"] = np.asarray(_point_colours(colour_rig, images, out["distance"][0]))
    result["candidates"] = np.asarray(candidates, np.float64)
    return result


INVALID = ("invalid pixels (valid = False): NaN in distance.npy, 0 in valid.png and False in "
           "valid.npy, black in inverse_distance.png and uncertainty.png, no point in "
           "points.ply")


def mark_invalid(result: dict) -> dict:
    """``result`` with ``distance``, ``inv_distance`` and ``entropy`` NaN where ``valid`` is
    False (the convention of every written file), whichever method produced it."""
    valid = np.asarray(result["valid"], bool)
    out = dict(result, valid=valid)
    for key in ("distance", "inv_distance", "entropy"):
        if key in result:
            out[key] = np.where(valid, np.asarray(result[key], np.float32), np.nan).astype(
                np.float32)
    return out


def _atomic_save_npy(path: Path, array: np.ndarray) -> None:
    import io

    buf = io.BytesIO()
    np.save(buf, array)
    write_bytes_atomic(path, buf.getvalue())


def _metre_ticks(d_min: float, d_max: float) -> dict:
    """Colour-bar ticks at round distances, placed in inverse distance, labelled in metres."""
    ticks = {}
    for d in (0.5, 0.75, 1, 1.5, 2, 3, 5, 10, 20, 50, 100, 200, 500, 1000):
        if d_min - 1e-9 <= d <= d_max + 1e-9:
            ticks[1.0 / d] = f"{d:g} m"
    return ticks


def write_prediction(result: dict, rig: Rig, out_dir: str | os.PathLike, title: str = "",
                     max_point_distance: float | None = None) -> dict:
    """Write a :func:`predict` result to ``out_dir``; returns {kind: path}.

    Files: ``distance.npy`` (H, W) float32 metres; ``valid.npy`` (H, W) bool and ``valid.png``
    (255 = valid, 0 = invalid); ``inverse_distance.png`` (colour map of 1/d with a colour bar
    labelled in metres); ``uncertainty.png`` (entropy in nats, 0 .. log D); ``points.ply``
    (binary, rig frame, metres, coloured from the images; points beyond
    ``max_point_distance``, by default the farthest candidate, are left out) and
    ``prediction.json`` (candidates, title, sizes, valid pixel count). Invalid pixels follow
    :data:`INVALID` in every file.
    """
    from gijax.io.paths import check_output_dir
    from gijax.viz.colormap import save_panorama_png  # matplotlib only where files are drawn
    from gijax.viz.pointcloud import panorama_points, write_ply

    out = check_output_dir(out_dir, "output folder")
    out.mkdir(parents=True, exist_ok=True)
    cand = np.asarray(result["candidates"], np.float64)
    d_min, d_max = float(cand[0]), float(cand[-1])
    result = mark_invalid(result)
    distance = np.asarray(result["distance"], np.float32)
    valid = np.asarray(result["valid"], bool)
    paths = {}
    paths["distance"] = str(out / "distance.npy")
    _atomic_save_npy(Path(paths["distance"]), distance)
    paths["valid"] = str(out / "valid.npy")
    _atomic_save_npy(Path(paths["valid"]), valid)
    paths["valid_png"] = str(out / "valid.png")
    write_bytes_atomic(Path(paths["valid_png"]),
                       cv2.imencode(".png", valid.astype(np.uint8) * 255)[1].tobytes())
    paths["inverse_distance_png"] = save_panorama_png(
        str(out / "inverse_distance.png"), result["inv_distance"], "distance (colour = 1/d)",
        1.0 / d_max, 1.0 / d_min, cmap="turbo", title=title, valid=valid,
        ticks=_metre_ticks(d_min, d_max))
    paths["uncertainty_png"] = save_panorama_png(
        str(out / "uncertainty.png"), result["entropy"], "entropy of the candidate "
        "distribution (nats)", 0.0, math.log(len(cand)), cmap="magma",
        title=(title + " - uncertainty").strip(" -"), valid=valid)
    limit = d_max if max_point_distance is None else max_point_distance
    points, keep = panorama_points(distance, np.asarray(rig.reference), valid=valid,
                                   max_distance=limit)
    colours = np.clip(np.asarray(result["colour"])[keep] * 255.0 + 0.5, 0, 255).astype(np.uint8)
    paths["points"] = write_ply(str(out / "points.ply"), points, colours)
    meta = {"title": title, "candidates_m": cand.tolist(), "shape": list(distance.shape),
            "valid_fraction": float(valid.mean()), "valid_pixels": int(valid.sum()),
            "invalid_pixels": INVALID, "points": int(len(points))}
    write_bytes_atomic(out / "prediction.json", json.dumps(meta, indent=2).encode())
    paths["meta"] = str(out / "prediction.json")
    return paths


def load_model(path: str | os.PathLike) -> tuple[OmniStereoNet, np.ndarray]:
    """A trained model (eval mode) and its training candidates (metres).

    ``path`` is a training run folder (``config.json`` plus orbax checkpoints; the best
    validated checkpoint is used when there is one) or an inference bundle
    (:mod:`gijax.train.bundle`).
    """
    from gijax.train.bundle import load_model as load_any

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such checkpoint / run folder")
    model, _, candidates = load_any(path)
    return model, np.asarray(candidates, np.float64)
