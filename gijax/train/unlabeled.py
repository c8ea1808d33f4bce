"""Losses that need no labels: what a predicted distance panorama must satisfy on its own.

Three terms, each a pure, traceable scalar function of the model's output and the batch's
surrogate images (jit, vmap, grad in the predicted inverse distance):

* :func:`photometric_loss`: each panorama pixel's predicted point is projected into every
  camera's surrogate image and the cameras' colours there are compared
  (:func:`gijax.sweep.consistency.view_dispersion`, masks respected); the right distance makes
  them agree. It serves both the candidate-list adaptation (:mod:`gijax.train.adapt`) and the
  label-free fine-tuning of a network (:class:`LabelFree`).
* :func:`edge_aware_smoothness`: the first differences of the mean-normalised inverse distance,
  each weighted by ``exp(-edge_scale * |colour difference|)`` of the reference panorama (the
  cameras' mean colour at the predicted points, :func:`reference_colours`, held constant), so
  that the map is smooth inside surfaces and free to jump at colour edges.
* :func:`teacher_loss`: the smooth L1 to a teacher's inverse distance (the classical baseline)
  where a confidence mask allows it (:func:`teacher_confidence`).

:class:`LabelFree` weighs them; :func:`label_free_terms` is the training objective a run with
``TrainConfig.label_free`` optimises instead of the label loss (:mod:`gijax.train.step`). No
function here reads a label.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from gijax.checks import bad_field
from gijax.geometry.panorama import Panorama, direction_to_pixel
from gijax.geometry.panorama_frame import panorama_rays
from gijax.geometry.rig import Rig
from gijax.geometry.visibility import OCCLUSION_MARGIN, visible_from
from gijax.sampling import bilinear_sample
from gijax.sweep.consistency import common_mean_gains, view_dispersion
from gijax.train.losses import RELEASE_INV_SCALE, smooth_l1

Array = jax.Array

# Two cameras' worth of (mask) weight: a point seen by fewer is not compared.
MIN_VIEW_WEIGHT = 1.5
# Keys a batch carries for the teacher term (besides the loader's surrogates and masks).
TEACHER_KEYS = ("teacher_inv", "teacher_mask")
# Fields the objective gained after run folders had stored it, with the value those runs
# optimised (before the occlusion test every camera that imaged a point was compared).
STORED_BEFORE = {"occlusion": 0.0}


def normalize_gain(surrogates: Array, masks: Array) -> Array:
    """Surrogates (B, N, Hs, Ws, 3) with each camera's colour channels scaled so that their
    mask-weighted mean equals the mean over the sample's cameras: cameras of another exposure,
    gain or white balance then compare (the classical baseline's ``normalize_gain`` on the
    surrogate images). ``masks`` (B, N, Hs, Ws); clipped to [0, 1]."""
    w = masks.astype(surrogates.dtype)[..., None]
    mean = jnp.sum(surrogates * w, axis=(2, 3)) / jnp.maximum(jnp.sum(w, axis=(2, 3)), 1e-6)
    gain = common_mean_gains(mean)                                        # (B, N, 3)
    return jnp.clip(surrogates * gain[:, :, None, None, :], 0.0, 1.0)


def camera_samples(surrogates: Array, masks: Array, rig: Rig, inv_distance: Array,
                   pano: Panorama, surrogate_pano: Panorama,
                   occlusion: float = 0.0) -> tuple[Array, Array]:
    """Every camera's colour at each panorama pixel's point ``reference + ray / inv_distance``.

    Args:
      surrogates: (B, N, Hs, Ws, 3) surrogate images in [0, 1] (each camera's hemisphere).
      masks: (B, N, Hs, Ws) their masks (1 = sees the world).
      rig: the rig (at the model's size; the panorama follows its panorama frame).
      inv_distance: (B, H, W) inverse distance, 1/m, on ``pano``.
      pano, surrogate_pano: the panorama and the surrogate images' hemisphere.
      occlusion: with a margin > 0 (static), a camera's weight is 0 where a nearer point of
        the same sample's panorama hides the point from the camera
        (:func:`gijax.geometry.visibility.visible_from` with that margin, bins of the
        panorama's width); 0 counts every point as seen.

    Returns ``(colours (N, B, H, W, 3), weights (N, B, H, W))``: bilinear samples and the
    sampled mask (0 where the point is outside the camera's hemisphere or hidden from it).
    """
    dtype = surrogates.dtype
    rays = panorama_rays(rig, pano, dtype)                               # (H, W, 3)
    dist = 1.0 / jnp.maximum(inv_distance.astype(dtype), 1e-6)
    pts = rig.reference.astype(dtype) + dist[..., None] * rays            # (B, H, W, 3)

    def one_camera(img, mask, rot, trans):
        # img (B, Hs, Ws, 3), mask (B, Hs, Ws): every sample's view from this camera.
        pc = (pts - trans.astype(dtype)) @ rot.astype(dtype)
        px, in_front = direction_to_pixel(surrogate_pano, pc)
        packed = jnp.concatenate([img, mask[..., None].astype(dtype)], -1)
        vals, ok = jax.vmap(bilinear_sample)(packed, px, in_front)
        weight = vals[..., 3] * ok.astype(dtype)
        if occlusion > 0:
            # Each sample's points hide only each other.
            seen = jax.vmap(lambda p: visible_from(p, trans, pano.width, occlusion))(pts)
            weight = weight * seen
        return vals[..., :3], weight

    return jax.vmap(one_camera, in_axes=(1, 1, 0, 0))(surrogates, masks, rig.rotations,
                                                      rig.translations)


def photometric_map(surrogates: Array, masks: Array, rig: Rig, inv_distance: Array,
                    pano: Panorama, surrogate_pano: Panorama) -> tuple[Array, Array]:
    """``(dispersion, seen)``, both (B, H, W): the cameras' colour disagreement at each pixel's
    point (:func:`gijax.sweep.consistency.view_dispersion`) and whether at least two cameras'
    worth of mask weight see it (1.0 or 0.0). Arguments as :func:`camera_samples`."""
    cols, wts = camera_samples(surrogates, masks, rig, inv_distance, pano, surrogate_pano)
    per_pixel, total = view_dispersion(cols, wts)
    return per_pixel, _seen(total)


def _seen(total: Array) -> Array:
    return (total >= MIN_VIEW_WEIGHT).astype(total.dtype)


def _mean_over(values: Array, seen: Array) -> Array:
    return jnp.sum(values * seen) / jnp.maximum(jnp.sum(seen), 1.0)


def _mean_colour(cols: Array, wts: Array) -> Array:
    total = jnp.sum(wts, axis=0)
    return jnp.sum(cols * wts[..., None], axis=0) / jnp.maximum(total, 1e-6)[..., None]


def photometric_loss(surrogates: Array, masks: Array, rig: Rig, inv_distance: Array,
                     pano: Panorama, surrogate_pano: Panorama) -> Array:
    """Colour disagreement between the cameras at the predicted panorama points (scalar):
    the mean of :func:`photometric_map`'s dispersion over the pixels it marks as seen (0 when
    there is none). Arguments as :func:`camera_samples`."""
    return _mean_over(*photometric_map(surrogates, masks, rig, inv_distance, pano,
                                       surrogate_pano))


def reference_colours(surrogates: Array, masks: Array, rig: Rig, inv_distance: Array,
                      pano: Panorama, surrogate_pano: Panorama) -> Array:
    """(B, H, W, 3) the reference panorama: at each pixel the cameras' mask-weighted mean
    colour at its point (0 where no camera sees it). Arguments as :func:`camera_samples`."""
    return _mean_colour(*camera_samples(surrogates, masks, rig, inv_distance, pano,
                                        surrogate_pano))


def edge_aware_smoothness(inv_distance: Array, colours: Array, edge_scale: float = 10.0) -> Array:
    """Edge-aware first-order smoothness of an inverse-distance panorama (scalar).

    Args:
      inv_distance: (B, H, W) inverse distance, 1/m.
      colours: (B, H, W, C) the reference panorama (e.g. :func:`reference_colours`); no
        gradient flows into it.
      edge_scale: how fast a colour edge frees the map: a difference weighs
        ``exp(-edge_scale * mean_c |dI|)``.

    Each sample's map is divided by its mean (a uniformly nearer or farther scene costs the
    same, so the term does not pull the scale). The horizontal differences wrap around (the
    panorama's columns span the full circle of longitude); the vertical ones do not. The loss
    is the mean of ``|dx| w_x`` over the H x W horizontal pairs plus the mean of ``|dy| w_y``
    over the (H - 1) x W vertical ones. Zero on a constant map.
    """
    inv = inv_distance / jnp.maximum(jnp.mean(inv_distance, axis=(-2, -1), keepdims=True), 1e-6)
    img = jax.lax.stop_gradient(colours.astype(inv.dtype))
    dx = jnp.roll(inv, -1, axis=-1) - inv
    dy = inv[..., 1:, :] - inv[..., :-1, :]
    wx = jnp.exp(-edge_scale * jnp.mean(jnp.abs(jnp.roll(img, -1, axis=-2) - img), axis=-1))
    wy = jnp.exp(-edge_scale * jnp.mean(jnp.abs(img[..., 1:, :, :] - img[..., :-1, :, :]),
                                        axis=-1))
    return jnp.mean(jnp.abs(dx) * wx) + jnp.mean(jnp.abs(dy) * wy)


def teacher_loss(inv_distance: Array, teacher_inv: Array, teacher_mask: Array,
                 scale: float = RELEASE_INV_SCALE) -> Array:
    """Mean smooth L1 between ``scale * inv_distance`` and ``scale * teacher_inv`` over the
    pixels ``teacher_mask`` trusts (scalar; 0 when it trusts none). All (B, H, W); the
    teacher's inverse distance is not differentiated (NaN where untrusted is allowed)."""
    m = teacher_mask.astype(inv_distance.dtype)
    target = jax.lax.stop_gradient(jnp.where(m > 0, teacher_inv, 0.0).astype(inv_distance.dtype))
    err = smooth_l1(scale * (inv_distance - target))
    return jnp.sum(jnp.where(m > 0, err, 0.0) * m) / jnp.maximum(jnp.sum(m), 1.0)


def teacher_confidence(surrogates: Array, masks: Array, rig: Rig, teacher_inv: Array,
                       teacher_valid: Array, pano: Panorama, surrogate_pano: Panorama,
                       max_dispersion: float) -> Array:
    """(B, H, W) float mask of the teacher pixels to trust: the teacher gave an estimate there
    (``teacher_valid``, its inverse distance finite and positive), at least two cameras see the
    point, and their colours agree there (:func:`photometric_map`'s dispersion at the
    teacher's distance at most ``max_dispersion``): the classical baseline's own matching
    cost lives in its reference cameras' views, so its match is re-scored where it is used."""
    ok = teacher_valid.astype(bool) & jnp.isfinite(teacher_inv) & (teacher_inv > 0)
    inv = jnp.where(ok, teacher_inv, 1.0).astype(surrogates.dtype)
    disp, seen = photometric_map(surrogates, masks, rig, inv, pano, surrogate_pano)
    return (ok & (seen > 0) & (disp <= max_dispersion)).astype(surrogates.dtype)


@dataclasses.dataclass(frozen=True)
class LabelFree:
    """The weights of the label-free objective (hashable: a static part of a compiled step).

    ``photometric``, ``smoothness`` and ``teacher`` weigh :func:`photometric_loss`,
    :func:`edge_aware_smoothness` (with ``edge_scale``) and :func:`teacher_loss`; a zero
    weight leaves its term out. The teacher term needs the batch's :data:`TEACHER_KEYS`.
    ``normalize_gain`` compares the cameras after :func:`normalize_gain` (real and rendered
    cameras differ in exposure; without it the photometric term barely sees the distance).
    ``occlusion`` > 0 leaves a camera out of the photometric term and the smoothness term's
    reference colours wherever a nearer predicted point hides the point from it (the margin
    of :func:`gijax.geometry.visibility.visible_from`; default :data:`OCCLUSION_MARGIN`, the
    calibration refinement's); 0 compares every camera that images the point. On renders of a
    5-camera ring 0.5 m wide the photometric term at the true distances fell from 0.033 to
    0.024 with it, and adaptation on them lowered the held-out error where without it it did
    not (``experiments/RESULTS.md``, "Label-free network adaptation").
    """

    photometric: float = 1.0
    smoothness: float = 0.01
    teacher: float = 0.0
    edge_scale: float = 10.0
    normalize_gain: bool = True
    occlusion: float = OCCLUSION_MARGIN

    def __post_init__(self):
        for field in ("photometric", "smoothness", "teacher", "edge_scale"):
            value = getattr(self, field)
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not value >= 0 or value == float("inf")):
                raise bad_field("LabelFree", field, "a finite number >= 0 (a weight)", value)
        if not (self.photometric or self.smoothness or self.teacher):
            raise ValueError("label-free objective: every weight is 0; give the photometric, "
                             "smoothness or teacher term a positive weight")
        if (isinstance(self.occlusion, bool) or not isinstance(self.occlusion, (int, float))
                or not 0 <= self.occlusion < 1):
            raise bad_field("LabelFree", "occlusion", "a margin in [0, 1) (0: off)",
                            self.occlusion)
        if not isinstance(self.normalize_gain, bool):
            raise bad_field("LabelFree", "normalize_gain", "true or false", self.normalize_gain)
        if self.smoothness and not (self.photometric or self.teacher):
            raise ValueError("label-free objective: smoothness alone has a trivial minimum "
                             "(a constant map); give the photometric or teacher term a weight")

    @classmethod
    def from_dict(cls, doc: dict) -> "LabelFree":
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(doc) - names)
        if unknown:
            raise ValueError(f"label-free objective: unknown fields {unknown}; expected "
                             f"{sorted(names)}")
        return cls(**doc)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def stored_objective(doc: dict) -> dict:
    """A run folder's stored :class:`LabelFree` weights with the fields it predates filled in
    as that run optimised them (:data:`STORED_BEFORE`), so that resuming compares like with
    like: a run stored before a field existed is not taken for one using the field's new
    default."""
    return {**STORED_BEFORE, **doc}


def label_free_terms(objective: LabelFree, inv_distance: Array, batch: dict, rig: Rig,
                     pano: Panorama) -> dict:
    """The weighted terms of ``objective`` (each a scalar, named after its weight) and their
    sum under ``'loss'``, for the predicted ``inv_distance`` (B, H, W) on ``pano``. ``batch``
    holds ``surrogates`` and ``masks`` (and, with a teacher weight, :data:`TEACHER_KEYS`);
    anything else in it (labels) is not read."""
    surrogates, masks = batch["surrogates"], batch["masks"]
    if objective.normalize_gain:
        surrogates = normalize_gain(surrogates, masks)
    inv = inv_distance.astype(surrogates.dtype)
    spano = Panorama.hemisphere(*surrogates.shape[2:4])
    terms = {}
    if objective.photometric or objective.smoothness:
        cols, wts = camera_samples(surrogates, masks, rig, inv, pano, spano,
                                   objective.occlusion)
        per_pixel, total = view_dispersion(cols, wts)
        if objective.photometric:
            terms["photometric"] = _mean_over(per_pixel, _seen(total))
        if objective.smoothness:
            terms["smoothness"] = edge_aware_smoothness(inv, _mean_colour(cols, wts),
                                                        objective.edge_scale)
    if objective.teacher:
        terms["teacher"] = teacher_loss(inv, batch["teacher_inv"], batch["teacher_mask"])
    weights = objective.to_dict()
    loss = sum(weights[k] * v for k, v in terms.items())   # only the terms it weighs
    return {"loss": loss, **terms}
