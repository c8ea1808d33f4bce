"""Inference: raw fisheye images -> distance panorama, and the files that show it.

Every method's result is a :class:`gijax.evaluate.prediction.Prediction`. The predictors of
one sample share one call, ``predict(rig, images, masks=None, log=None)``: the learned model
(:class:`LearnedPredictor`, around :func:`predict`), the classical baseline
(:class:`RtssPredictor`) and an exported ONNX file
(:class:`gijax.export.ort_predict.OnnxPredictor`). For evaluation over a dataset,
:func:`learned_batch_predictor` (surrogate images, as the data loader makes them),
:class:`LearnedImagePredictor` and :class:`RtssBatchPredictor` (raw fisheye images, as
:func:`sample_batches` reads them) predict whole batches for
:func:`gijax.evaluate.loop.evaluate_predictions`.

:func:`predict` has no side effects but is not traceable: it is the eager edge for one sample
(numpy in, numpy out; inputs checked with errors that name them). Images of another size are
handled by :func:`fit_images`, the one size policy of every method: resized when the aspect
ratio is the rig's, refused otherwise. The traceable core is the network call on surrogate
images: raw images resampled to the model's surrogate images, then ``model(surrogates, masks,
grids)`` (:func:`gijax.model.on_fisheye_images`) with
the sweep grids of :func:`gijax.model.model_grids`, in eval mode (BatchNorm running
statistics).
:func:`write_prediction` writes the results: the distance panorama as float32 ``.npy``,
colour-mapped PNGs with colour bars (distance and, for the learned model, uncertainty), the
colour panorama ``rgb.png`` (each pixel the mean colour of its predicted point over the cameras
that see it, :func:`point_colours`), a coloured point cloud (``.ply``) and the per-pixel
validity.

Invalid pixels (seen by fewer cameras than a distance needs: the model's ``valid`` output, or
RTSS's) follow one convention in every file, whichever method made them (:data:`INVALID`):
NaN in ``distance.npy`` (never inf), False / 0 in ``valid.npy`` / ``valid.png``, black in the
colour maps and ``rgb.png``, absent from ``points.ply``, and counted in ``prediction.json``.
The in-memory result of :func:`predict` keeps the network's raw values there, marked only by
``valid``.
"""

from __future__ import annotations

import functools
import json
import math
import os
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from gijax.evaluate.labels import usable_label
from gijax.evaluate.prediction import Prediction
from gijax.geometry.panorama import Panorama
from gijax.geometry.panorama_frame import coverage_of, panorama_rays, panorama_rotation
from gijax.data.images import fit_images
from gijax.geometry.rig import Rig, project_rig_points
from gijax.io.replace import FolderKind
from gijax.model import (OmniStereoNet, check_model_candidates, coverage_note, model_grids,
                         model_panorama, model_rig, on_fisheye_images)
from gijax.nn.presets import ModelConfig
from gijax.sampling import bilinear_sample
from gijax.sweep.grids import surrogate_resampling
from gijax.sweep.surrogate import as_float_image, check_images

Array = jax.Array


# Every output of the network, as predict() returns them.
_MAPS = ("inv_distance", "distance", "prob", "entropy", "valid")


@functools.partial(jax.jit, static_argnames=("graphdef", "pano", "outputs"))
def _network_on_images(graphdef, state, images, masks, rig, candidates, pano: Panorama,
                       outputs: tuple) -> dict:
    """The network (``graphdef`` with ``state``, in the mode the state holds) on raw fisheye
    images (B, N, h, w, 3), uint8 or float in [0, 1], at the size of ``rig``: the ``outputs``
    named, over ``pano``. The one compiled program of the learned model's predictions (one
    sample, or batches in :class:`LearnedImagePredictor`)."""
    model = nnx.merge(graphdef, state)
    cfg = model.config
    out = on_fisheye_images(model, as_float_image(images), masks,
                            surrogate_resampling(rig, cfg.surrogate_hw),
                            model_grids(cfg, rig, candidates, pano))
    return {k: out[k] for k in outputs}


def _eval_split(model: OmniStereoNet):
    """(graphdef, state) of an eval-mode view of ``model`` (the model's own mode is kept)."""
    graphdef, state = nnx.split(model)
    view = nnx.merge(graphdef, state)
    view.eval()
    return nnx.split(view)


@functools.partial(jax.jit, static_argnames=("pano",))
def _point_colours(rig: Rig, images: Array, distance: Array, pano: Panorama) -> Array:
    """(H, W, 3) mean colour of each predicted point over the cameras that see it (projection
    valid and inside the rig's masks); 0 where no camera sees it."""
    points = rig.reference + distance[..., None] * panorama_rays(rig, pano, distance.dtype)
    pixels, seen = project_rig_points(rig, points)
    colours, seen = jax.vmap(bilinear_sample)(images, pixels, seen)
    # Averaging rather than taking one camera evens out per-camera exposure and white balance
    # and never depends on a camera order.
    weight = seen.astype(colours.dtype)[..., None]
    total = jnp.sum(colours * weight, axis=0)
    count = jnp.sum(weight, axis=0)
    return jnp.where(count > 0, total / jnp.maximum(count, 1.0), 0.0)


def point_colours(rig: Rig, images, masks, distance, pano: Panorama | None = None) -> np.ndarray:
    """(H, W, 3) colour in [0, 1] of each point of a distance panorama (any method's): the mean
    of its bilinear samples in every camera that sees it, 0 where none does.

    ``images`` (N, h, w, 3) at the rig's size, ``masks`` (N, h, w) in place of the rig's own
    (None keeps them). Points without a distance (NaN or not positive) are coloured as if 1 m
    away; every written file leaves them out or black. ``pano`` is the distance map's panorama
    (default: the hemisphere of its size), oriented by the rig's panorama frame.
    """
    if masks is not None:
        rig = rig.replace(masks=tuple(jnp.asarray(m, jnp.float32) for m in masks))
    distance = np.asarray(distance, np.float32)
    distance = np.where(usable_label(distance), distance, 1.0)
    pano = pano or Panorama.hemisphere(*distance.shape)
    if pano.shape != distance.shape:
        raise ValueError(f"distance has shape {distance.shape} but the panorama is "
                         f"{pano.height} x {pano.width}")
    return np.asarray(_point_colours(rig, as_float_image(images), jnp.asarray(distance), pano))


# The colour panorama is sampled at most this many times finer than the distance map.
MAX_COLOUR_FACTOR = 8


def colour_factor(rig: Rig, pano: Panorama) -> int:
    """How many times finer than ``pano`` the cameras resolve the scene: the smallest focal
    length (pixels per radian at the optical axis) over the panorama's pixels per radian of
    latitude, rounded, in 1 .. :data:`MAX_COLOUR_FACTOR`."""
    focal = min(min(float(c.fx), float(c.fy)) for c in rig.cameras)
    per_radian = pano.height / (pano.lat_max - pano.lat_min)
    return int(np.clip(round(focal / per_radian), 1, MAX_COLOUR_FACTOR))


def colour_panorama(rig: Rig, images, masks, distance, valid, pano: Panorama
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The colour panorama at the resolution the cameras support: ``(rgb (kH, kW, 3) in
    [0, 1], valid (kH, kW))`` with k = :func:`colour_factor`. The distance map is upsampled
    (bilinear in inverse distance, validity by nearest neighbour) and every finer point is
    coloured from the images as :func:`point_colours` does; k = 1 is ``point_colours`` itself.

    ``rig`` and ``images`` at the cameras' own size (not the network's), so a model run on
    downscaled images still shows what the cameras saw."""
    import cv2

    k = colour_factor(rig, pano)
    distance = np.asarray(distance, np.float32)
    valid = np.asarray(valid, bool) & usable_label(distance)
    if k == 1:
        return point_colours(rig, images, masks, distance, pano), valid
    fine = Panorama(pano.height * k, pano.width * k, pano.lat_min, pano.lat_max)
    inv = np.where(valid, 1.0 / np.where(valid, distance, 1.0), 0.0).astype(np.float32)
    fill = float(np.median(inv[valid])) if valid.any() else 1.0
    inv = np.where(valid, inv, fill).astype(np.float32)
    inv_fine = cv2.resize(inv, (fine.width, fine.height), interpolation=cv2.INTER_LINEAR)
    valid_fine = cv2.resize(valid.astype(np.uint8), (fine.width, fine.height),
                            interpolation=cv2.INTER_NEAREST).astype(bool)
    dist_fine = 1.0 / np.maximum(inv_fine, 1e-6)
    return point_colours(rig, images, masks, dist_fine, fine), valid_fine


def model_size(config: ModelConfig, rig: Rig) -> tuple[int, int]:
    """(height, width) of the images the learned model runs on: the rig's size times the
    configuration's ``image_scale``, rounded as :func:`gijax.geometry.rig.scale_rig` rounds."""
    cam = rig.cameras[0]
    return (int(round(cam.height * config.image_scale)),
            int(round(cam.width * config.image_scale)))


def predict(model: OmniStereoNet, rig: Rig, images, masks, candidates, log=None,
            pano: Panorama | None = None, colours: bool = True) -> Prediction:
    """Distance panorama of one sample.

    Args:
      model: an :class:`OmniStereoNet` (its mode is not changed: eval mode is applied to a view).
      rig: the rig at its calibrated image size.
      images: (N, h, w, 3) raw fisheye images, uint8 or float RGB in [0, 1], of the rig's
        aspect ratio; resized to the rig's size times ``model.config.image_scale``
        (:func:`fit_images`).
      masks: (N, h, w) validity masks (1 = sees the world) or None for the rig's own masks.
      candidates: (D,) ascending distances in metres, D = the model's candidate count.
      log: receives the note when the images are resized, and the warning when ``pano``
        covers another part of the sphere than the model was trained on.
      pano: the output panorama (static), oriented by the rig's panorama frame; default the
        model's own (:func:`gijax.model.model_panorama`).
      colours: also make ``rgb`` / ``rgb_valid``, the colour panorama at the resolution the
        cameras support (:func:`colour_panorama`, from the images at the rig's own size).

    Returns:
      a :class:`Prediction` of numpy arrays: ``inv_distance`` (H, W) 1/m, ``distance`` (H, W)
      m, ``prob`` (D, H, W), ``entropy`` (H, W) nats, ``valid`` (H, W) bool, ``colour``
      (H, W, 3) in [0, 1] (the image colour at each predicted point), ``candidates`` (D,) and
      ``panorama`` (the :class:`Panorama` of those maps).
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
    check_model_candidates(config, candidates)
    pano = model_panorama(config) if pano is None else pano
    note = coverage_note(config, pano)
    if note and log is not None:
        log(note)
    if config.cost_volume == "concat" and rig.num_cameras != config.num_cameras:
        raise ValueError(f"model {config.name!r} concatenates exactly {config.num_cameras} cameras;"
                         f" the rig has {rig.num_cameras}")
    if masks is not None:
        masks = np.asarray(masks)
        if masks.shape != images.shape[:3]:
            raise ValueError(f"masks must have shape {images.shape[:3]} to match the images; "
                             f"found {masks.shape}")
    full_rig, full_images, full_masks = fit_images(rig, images, masks, None, None)
    run_rig, images, masks = fit_images(rig, images, masks, model_size(config, rig), log)
    check_images(run_rig, images, masks)
    images = as_float_image(images)
    if masks is None:
        masks = np.stack([np.ones((c.height, c.width), np.float32) if m is None else np.asarray(m)
                          for c, m in zip(run_rig.cameras, run_rig.masks)])
    graphdef, state = _eval_split(model)
    cand = jnp.asarray(candidates, jnp.float32)
    out = _network_on_images(graphdef, state, images[None],
                             jnp.asarray(masks, jnp.float32)[None], model_rig(run_rig), cand,
                             pano, _MAPS)
    maps = {k: np.asarray(out[k][0]) for k in _MAPS}
    rgb, rgb_valid = (colour_panorama(full_rig, full_images, full_masks, maps["distance"],
                                      maps["valid"], pano) if colours else (None, None))
    return Prediction(**maps,
                      colour=point_colours(run_rig, images, masks, out["distance"][0], pano),
                      rgb=rgb, rgb_valid=rgb_valid,
                      candidates=np.asarray(candidates, np.float64), panorama=pano)


class LearnedPredictor:
    """A learned model with its candidates and output panorama, as a :class:`Predictor`
    (:func:`predict` for each sample)."""

    def __init__(self, model: OmniStereoNet, candidates, pano: Panorama | None = None,
                 colours: bool = True):
        self.model = model
        self.candidates = np.asarray(candidates, np.float64)
        self.pano = pano
        self.colours = colours

    def predict(self, rig: Rig, images, masks=None, log=None) -> Prediction:
        return predict(self.model, rig, images, masks, self.candidates, log=log, pano=self.pano,
                       colours=self.colours)


class RtssPredictor:
    """The classical baseline (an RTSS preset) as a :class:`Predictor`.

    Images of the rig's aspect ratio but another size are matched at their own size, the
    lenses rescaled (:func:`fit_images` without a target size). ``candidates`` None takes the
    preset's own list for the rig; ``pano`` None the hemisphere of the preset's default size
    (160 x 640). The result has no ``entropy`` or ``prob``: winner-take-all has no candidate
    distribution, and a constant map would read as "certain everywhere". ``colours`` False
    skips the colour panorama (it costs a projection into every camera).
    """

    def __init__(self, preset: str = "RS-E32", candidates=None, pano: Panorama | None = None,
                 colours: bool = True):
        self.preset = preset
        self.candidates = None if candidates is None else np.asarray(candidates, np.float64)
        self.pano = pano
        self.colours = colours

    def predict(self, rig: Rig, images, masks=None, log=None) -> Prediction:
        from gijax.baseline import rtss        # looked up at call time, like every entry point

        rig, images, masks = fit_images(rig, np.asarray(images), masks, None, log=log)
        sample = {"images": images}
        if masks is not None:
            sample["masks"] = masks
        pano = Panorama.hemisphere(160, 640) if self.pano is None else self.pano
        cand = (np.asarray(rtss.preset_candidates(rig, rtss.get_rtss_preset(self.preset)),
                           np.float64) if self.candidates is None else self.candidates)
        out = rtss.rtss_predict_sample(rig, sample, self.preset, candidates=cand, pano=pano)
        distance = np.asarray(out["distance"], np.float32)
        return Prediction(
            inv_distance=np.asarray(out["inv_distance"], np.float32), distance=distance,
            valid=np.asarray(out["valid"], bool), candidates=cand, panorama=pano,
            colour=point_colours(rig, images, masks, distance, pano) if self.colours else None)


def learned_batch_predictor(model: OmniStereoNet, rig: Rig, candidates, pano: Panorama):
    """``batch -> Prediction`` of a learned model on batches of surrogate images
    (``surrogates`` (B, Ncam, Hs, Ws, 3), ``masks`` (B, Ncam, Hs, Ws), as
    :class:`gijax.data.Loader` yields them) for the output panorama ``pano``; compiled once
    per batch shape. The network gives an estimate at every pixel."""
    graphdef, state = nnx.split(model)

    @jax.jit
    def run(state, surrogates, masks, rig, cand):
        model = nnx.merge(graphdef, state)
        grids = model_grids(model.config, rig, cand, pano)
        return model(surrogates, masks, grids)["inv_distance"]

    cand = jnp.asarray(candidates, jnp.float32)
    run_rig = model_rig(rig)

    def predict_batch(batch: dict) -> Prediction:
        inv = run(state, jnp.asarray(batch["surrogates"]), jnp.asarray(batch["masks"]),
                  run_rig, cand)
        return Prediction(inv_distance=inv, valid=jnp.ones(inv.shape, bool))

    return predict_batch


class LearnedImagePredictor:
    """``batch -> Prediction`` of a learned model on batches of raw fisheye images, the
    resampling to surrogate images inside the one compiled call (so a timed call costs what a
    deployed one does): ``batch['images']`` (B, N, h, w, 3) uint8 or float in [0, 1] at the
    size of ``rig`` (the model's image size, :func:`model_size`), ``batch['masks']``
    (B, N, h, w). Like :func:`learned_batch_predictor` it scores every pixel (``valid`` all
    True). :meth:`lower` gives the compiled program's lowering for a batch (XLA's memory and
    cost analysis; compiling it again reuses the program the calls run). It runs the program
    :func:`predict` runs for a sample (the same outputs asked for), so the two agree to the
    bit on the same inputs."""

    def __init__(self, model: OmniStereoNet, rig: Rig, candidates, pano: Panorama | None = None):
        if model.config.cost_volume == "concat" and rig.num_cameras != model.config.num_cameras:
            raise ValueError(f"model {model.config.name!r} concatenates exactly "
                             f"{model.config.num_cameras} cameras; the rig has {rig.num_cameras}")
        self.graphdef, self.state = _eval_split(model)
        self.rig = model_rig(rig)
        self.candidates = np.asarray(candidates, np.float64)
        self.pano = model_panorama(model.config) if pano is None else pano

    def _args(self, batch: dict) -> tuple:
        # Converted to float as predict() converts them, so both run one program.
        return (self.graphdef, self.state, as_float_image(batch["images"]),
                jnp.asarray(batch["masks"], jnp.float32), self.rig,
                jnp.asarray(self.candidates, jnp.float32), self.pano, _MAPS)

    def __call__(self, batch: dict) -> Prediction:
        inv = _network_on_images(*self._args(batch))["inv_distance"]
        return Prediction(inv_distance=inv, valid=jnp.ones(inv.shape, bool))

    def lower(self, batch: dict):
        return _network_on_images.lower(*self._args(batch))


def sample_batches(reader, batch_size: int):
    """A dataset reader's samples in order, in batches, for predictors of raw fisheye images
    (:class:`LearnedImagePredictor`, :class:`RtssBatchPredictor`): ``index`` (B,),
    ``images`` (B, N, h, w, 3) uint8, ``masks`` (B, N, h, w) float32, ``distance``
    (B, H, W) float32 metres and ``valid`` (B, H, W) (usable labels)."""
    for start in range(0, len(reader), batch_size):
        indices = np.arange(start, min(start + batch_size, len(reader)))
        samples = [reader[int(i)] for i in indices]
        dist = np.stack([np.asarray(s["pano_distance"], np.float32) for s in samples])
        yield {"index": indices, "images": np.stack([s["images"] for s in samples]),
               "masks": np.stack([np.asarray(s["masks"], np.float32) for s in samples]),
               "distance": dist, "valid": usable_label(dist)}


class RtssBatchPredictor:
    """``batch -> Prediction`` of the classical baseline (an RTSS configuration) on batches of
    raw fisheye images (``images`` (B, N, h, w, 3) uint8 or float in [0, 1], ``masks``
    (B, N, h, w), as :func:`sample_batches` yields them), one sample per compiled call;
    ``rig`` at the images' size. :meth:`lower` gives the lowering of one sample's call."""

    def __init__(self, rig: Rig, candidates, pano: Panorama, config):
        self.rig = rig
        self.candidates = np.asarray(candidates, np.float64)
        self.pano = pano
        self.config = config

    def _args(self, images, masks) -> tuple:
        return (self.rig, as_float_image(images), jnp.asarray(masks, jnp.float32),
                jnp.asarray(self.candidates, jnp.float32))

    def __call__(self, batch: dict) -> Prediction:
        from gijax.baseline.rtss import rtss_predict

        invs, valids = [], []
        for images, masks in zip(batch["images"], batch["masks"]):
            out = rtss_predict(*self._args(images, masks), self.pano, self.config)
            invs.append(out["inv_distance"])
            valids.append(out["valid"])
        return Prediction(inv_distance=jnp.stack(invs), valid=jnp.stack(valids))

    def lower(self, batch: dict):
        from gijax.baseline.rtss import sphere_sweep

        return sphere_sweep.lower(*self._args(batch["images"][0], batch["masks"][0]),
                                  pano=self.pano, config=self.config)


INVALID = ("invalid pixels (valid = False): NaN in distance.npy, 0 in valid.png and False in "
           "valid.npy, black in inverse_distance.png, uncertainty.png and rgb.png, no point in "
           "points.ply")


def mark_invalid(result: dict) -> dict:
    """``result`` with ``distance``, ``inv_distance`` and ``entropy`` NaN where ``valid`` is
    False (the convention of every written file), whichever method produced it. A distance
    that is not a finite positive number is invalid too, so no file ever holds inf."""
    distance = np.asarray(result["distance"], np.float32)
    valid = np.asarray(result["valid"], bool) & usable_label(distance)
    out = dict(result, valid=valid)
    for key in ("distance", "inv_distance", "entropy"):
        if key in result:
            out[key] = np.where(valid, np.asarray(result[key], np.float32), np.nan).astype(
                np.float32)
    return out


def _metre_ticks(d_min: float, d_max: float) -> dict:
    """Colour-bar ticks at round distances, placed in inverse distance, labelled in metres."""
    ticks = {}
    for d in (0.5, 0.75, 1, 1.5, 2, 3, 5, 10, 20, 50, 100, 200, 500, 1000):
        if d_min - 1e-9 <= d <= d_max + 1e-9:
            ticks[1.0 / d] = f"{d:g} m"
    return ticks


PREDICTION_RECORD = "prediction.json"
PREDICTION = FolderKind(
    "prediction folder", "prediction",
    frozenset({"distance.npy", "valid.npy", "valid.png", "inverse_distance.png",
               "uncertainty.png", "rgb.png", "points.ply", PREDICTION_RECORD}),
    record=PREDICTION_RECORD)


def check_prediction_folder(out_dir: str | os.PathLike, inputs=()) -> Path:
    """``out_dir`` as a Path when a prediction may be written there: a new path, an empty
    folder, or an earlier prediction (its files only, ``prediction.json`` among them) that holds
    none of ``inputs``; else ValueError, one line. Call it before predicting."""
    from gijax.io.replace import check_replaceable

    return check_replaceable(out_dir, PREDICTION, inputs)


def write_prediction(result: dict, rig: Rig, out_dir: str | os.PathLike, title: str = "",
                     max_point_distance: float | None = None, inputs=()) -> dict:
    """Write a :func:`predict` result to ``out_dir``; returns {kind: path}.

    Files: ``distance.npy`` (H, W) float32 metres; ``valid.npy`` (H, W) bool and ``valid.png``
    (255 = valid, 0 = invalid); ``inverse_distance.png`` (colour map of 1/d with a colour bar
    labelled in metres); ``uncertainty.png`` (entropy in nats, 0 .. log D; only when the result
    has an ``entropy``: the classical baseline has no candidate distribution and writes none);
    ``rgb.png`` (H, W) the colour panorama (``colour``, black where invalid); ``points.ply``
    (binary, rig frame, metres, coloured from the images; points beyond
    ``max_point_distance``, by default the farthest candidate, are left out) and
    ``prediction.json`` (candidates, title, sizes, valid pixel count). Invalid pixels follow
    :data:`INVALID` in every file.

    The folder is written whole: new, or replacing an earlier prediction (never another
    folder, :func:`check_prediction_folder`), assembled beside it and swapped in, so that a
    stop half way (Ctrl-C, a full disk) leaves the earlier prediction as it was and never a
    mix of old and new files (:func:`gijax.io.replace.replace_folder`).
    """
    from gijax.io.replace import replace_folder

    out = check_prediction_folder(out_dir, inputs)
    names = replace_folder(out, PREDICTION, lambda tmp: _write_prediction_files(
        result, rig, tmp, title, max_point_distance), inputs)
    return {kind: str(out / name) for kind, name in names.items()}


def _write_prediction_files(result: dict, rig: Rig, out: Path, title: str,
                            max_point_distance: float | None) -> dict:
    """The files of :func:`write_prediction`, written plainly into the new folder ``out``;
    returns {kind: file name}."""
    from gijax.viz.colormap import save_panorama_png  # matplotlib only where files are drawn
    from gijax.viz.pointcloud import panorama_points, write_ply

    cand = np.asarray(result["candidates"], np.float64)
    d_min, d_max = float(cand[0]), float(cand[-1])
    result = mark_invalid(result)
    distance = np.asarray(result["distance"], np.float32)
    valid = np.asarray(result["valid"], bool)
    paths = {}
    paths["distance"] = str(out / "distance.npy")
    np.save(paths["distance"], distance)
    paths["valid"] = str(out / "valid.npy")
    np.save(paths["valid"], valid)
    paths["valid_png"] = str(out / "valid.png")
    Path(paths["valid_png"]).write_bytes(
        cv2.imencode(".png", valid.astype(np.uint8) * 255)[1].tobytes())
    paths["inverse_distance_png"] = save_panorama_png(
        str(out / "inverse_distance.png"), result["inv_distance"], "distance (colour = 1/d)",
        1.0 / d_max, 1.0 / d_min, cmap="turbo", title=title, valid=valid,
        ticks=_metre_ticks(d_min, d_max))
    if "entropy" in result:
        paths["uncertainty_png"] = save_panorama_png(
            str(out / "uncertainty.png"), result["entropy"], "entropy of the candidate "
            "distribution (nats)", 0.0, math.log(len(cand)), cmap="magma",
            title=(title + " - uncertainty").strip(" -"), valid=valid)
    # The colour panorama at the cameras' resolution where the method made one (a learned
    # model's distance map is coarser than its images), else its colour per predicted point.
    if "rgb" in result:
        colour, colour_valid = np.asarray(result["rgb"], np.float32), np.asarray(
            result["rgb_valid"], bool)
    else:
        colour, colour_valid = np.asarray(result["colour"], np.float32), valid
    rgb = np.where(colour_valid[..., None], colour, 0.0)
    rgb = np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)
    paths["rgb_png"] = str(out / "rgb.png")
    Path(paths["rgb_png"]).write_bytes(
        cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))[1].tobytes())
    limit = d_max if max_point_distance is None else max_point_distance
    pano = result.get("panorama") or Panorama.hemisphere(*distance.shape)
    points, keep = panorama_points(distance, np.asarray(rig.reference), pano, valid=valid,
                                   max_distance=limit, rotation=panorama_rotation(rig))
    colours = np.clip(np.asarray(result["colour"])[keep] * 255.0 + 0.5, 0, 255).astype(np.uint8)
    paths["points"] = write_ply(str(out / "points.ply"), points, colours)
    meta = {"title": title, "candidates_m": cand.tolist(), "shape": list(distance.shape),
            "valid_fraction": float(valid.mean()), "valid_pixels": int(valid.sum()),
            "invalid_pixels": INVALID, "points": int(len(points)),
            # What points.ply leaves out of the valid pixels, and why: far points (sky, the
            # candidate list's far end) would dwarf the scene in a viewer.
            "points_left_out": {"pixels": int(valid.sum() - len(points)),
                                "reason": f"distance beyond {limit:g} m (max_point_distance, "
                                          f"by default the farthest candidate)"},
            "panorama": {"coverage": coverage_of(pano),
                         "latitude_deg": [math.degrees(pano.lat_min), math.degrees(pano.lat_max)],
                         "longitude": "column grows to the right seen from the centre, pole "
                                      "(row 0) up; 0 deg in the middle column",
                         "rotation_panorama_to_rig": np.asarray(panorama_rotation(rig),
                                                                np.float64).tolist()}}
    (out / PREDICTION_RECORD).write_bytes(json.dumps(meta, indent=2).encode())
    paths["meta"] = str(out / PREDICTION_RECORD)
    return {k: Path(v).name for k, v in paths.items()}
