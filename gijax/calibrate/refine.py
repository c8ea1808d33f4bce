"""Calibration refinement from unlabeled images: camera poses (and optionally focal lengths and
principal points) that make the cameras agree about what they see.

Method (photometric bundle adjustment on panorama distance maps):

* Per frame, an inverse-distance panorama around the rig's reference point (its panorama
  frame, hemisphere or sphere as :func:`gijax.geometry.panorama_frame.choose_panorama`
  decides), initialised from the classical baseline (:func:`gijax.baseline.rtss.rtss_predict`)
  run with the initial calibration. Each panorama point ``reference + ray / inv`` is projected
  into every camera (:func:`gijax.geometry.cameras.project`) and the camera's image sampled
  there (:func:`gijax.sampling.bilinear_sample`), its mask with it.
* Data term: the robust dispersion of the cameras' samples at each point
  (:func:`gijax.sweep.consistency.view_dispersion`, the same measure as the photometric
  candidate adaptation), averaged over points that at least two cameras' worth of mask see.
  The images are gain-normalised per camera and channel (so exposure differences are not
  disagreement), flattened (each pixel divided by its neighbourhood's mean, so vignetting is
  not disagreement either) and blurred within their masks.
* Smoothness: an edge-aware total variation of the log inverse distance (weights fall where
  the panorama's colour changes), which keeps the distance maps from absorbing pose errors
  in textureless regions.
* Parameters: per camera a rotation vector ``w_i`` and a translation ``dt_i`` applied to the
  initial pose, ``R_i = R_i0 exp([w_i]x)`` (a turn of the camera about its own centre, as
  :mod:`gijax.data.calibration_error` perturbs) and ``t_i = t_i0 + dt_i``; optionally a focal
  scale ``exp(s_i)`` (fx and fy together) and a principal point shift; and the frames' log
  inverse-distance maps. Adam (optax) on all of them jointly, with a learning rate per
  parameter kind, coarse to fine: the images are blurred strongly first (a wide basin of
  convergence: a pose error of several pixels still leaves the blurred images overlapping),
  then less.

Why joint optimisation rather than alternating sweeps: the distance maps are the only
unknown that couples frames, and with them free the pose gradient is that of the photometric
error at the current best geometry, not at a stale one; RTSS gives them a start within the
basin. Why a panorama around the reference point rather than per-camera depth: one map per
frame serves any number of cameras, and it is the geometry every other part of gijax works in.

The gauge. Images alone cannot fix where the rig is nor how large it is: moving every camera
by one rigid motion, or scaling every translation and every distance together, leaves every
image the same. Refinement therefore holds **camera 0's pose fixed** (its rotation and
translation are not parameters) and the **distance between cameras 0 and 1** (camera 1's
translation moves on the sphere of that radius around camera 0:
``t_1 = t_0 + |t_10| unit(t_10 + dt_1)``, ``t_10 = t_1,0 - t_0``). Errors against a true rig
are measured modulo that gauge (:func:`gauge_aligned_errors`).

Pure and traceable: :func:`apply_calibration`, :func:`prepare_images`,
:func:`frame_samples`, :func:`frame_terms`, :func:`refinement_loss`. The loop at the edge
(:func:`refine_rig`: RTSS initialisation, checks on concrete frames, progress bar) and the
reports (:func:`pose_change`, :func:`align_gauge`, :func:`gauge_aligned_errors`,
:func:`frame_texture`, :func:`frame_overlap`, :func:`transfer_refinement`) are not traced.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Callable, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from gijax.checks import bad_field
from gijax.data.photometric import gaussian_blur
from gijax.evaluate.labels import usable_label
from gijax.geometry import cameras as cam_lib
from gijax.geometry.panorama import Panorama
from gijax.geometry.panorama_frame import choose_panorama, panorama_of, panorama_rays, \
    with_panorama_rotation
from gijax.geometry.rig import Rig, is_homogeneous
from gijax.geometry.rotations import axis_angle_to_matrix
from gijax.geometry.visibility import OCCLUSION_MARGIN, visible_from
from gijax.sampling import bilinear_sample
from gijax.sweep.consistency import view_dispersion

Array = jax.Array

# Inverse distances are kept inside [1 / MAX_DISTANCE, 1 / MIN_DISTANCE] (metres).
MIN_DISTANCE = 0.2
MAX_DISTANCE = 200.0
GAUGE = ("camera 0's pose is held fixed and the distance between cameras 0 and 1 is held "
         "(images fix neither where the rig is nor its scale)")
# A point counts as compared when at least this much camera weight sees it (two cameras).
SEEN_WEIGHT = 1.5


@dataclasses.dataclass(frozen=True)
class RefineConfig:
    """Settings of the refinement (hashable: static under ``jit``).

    Attributes:
      steps: Adam steps in all, split evenly over the ``blur`` levels.
      blur: Gaussian blur sigma of each coarse-to-fine level, in working-image pixels.
      intrinsics: also refine every camera's focal length (fx, fy by one factor) and
        principal point.
      pano_hw: (H, W) of the hemisphere the distance maps use (a sphere is (2H, W)).
      lr_rotation, lr_translation, lr_focal, lr_centre, lr_depth: Adam step sizes of the
        rotation vectors (rad), translations (m), log focal scales, principal points (px) and
        log inverse distances; they decay by a cosine to ``lr_floor`` of themselves.
      smoothness: weight of the edge-aware smoothness of the log inverse distance.
      edge_scale: colour difference at which the smoothness weight falls to 1/e.
      min_texture: the least intensity contrast (standard deviation over the valid pixels,
        intensities in [0, 1]) a camera's image must have in every frame.
      min_overlap: the least fraction of a frame's panorama that two cameras must see at the
        initial distances.
      flatten: width of the neighbourhood each pixel's brightness is divided by (a Gaussian's
        sigma as a fraction of the image width; 0: none, only one gain per camera and
        channel), see :func:`prepare_images`. Rendered fisheyes darkened up to 35 % towards
        the rim, differently per camera: a refinement started at the true poses drifted 6 mm
        without it and under 1 mm with 0.05.
      occlusion: the margin of the test whether a camera sees a panorama point or a nearer
        point hides it (relative, in inverse distance; 0: every point counts as seen), see
        :func:`gijax.geometry.visibility.visible_from`. Cameras 1 m apart see different
        stretches of a wall behind a post: comparing them there pulled the poses of the
        widest built-in rig 1.8-4.6 mm off in a refinement started at the true poses
        (1.0-2.7 mm with 0.05).
      rounds: how many times the whole schedule runs. Every round after the first starts
        again from the classical baseline's distances, now matched at the calibration the
        previous round reached, with a fresh optimiser: the first round's starting distances
        were matched at the wrong calibration, and a translation error can hide in them
        (moving a camera and bending the distances together keeps the photometric agreement).
    """

    steps: int = 300
    blur: tuple = (3.0, 1.5, 0.7)
    intrinsics: bool = False
    pano_hw: tuple = (48, 192)
    lr_rotation: float = 1e-3
    lr_translation: float = 1e-3
    lr_focal: float = 1e-3
    lr_centre: float = 0.05
    lr_depth: float = 0.03
    lr_floor: float = 0.05
    smoothness: float = 0.02
    edge_scale: float = 0.05
    min_texture: float = 0.02
    min_overlap: float = 0.05
    flatten: float = 0.05
    occlusion: float = OCCLUSION_MARGIN
    rounds: int = 1

    def __post_init__(self):
        if not self.blur or any(not s > 0 for s in self.blur):
            raise bad_field("RefineConfig", "blur", "sigmas > 0 pixels (at least one)",
                            self.blur)
        if int(self.steps) < len(self.blur):
            raise bad_field("RefineConfig", "steps",
                            f"at least one per blur level ({len(self.blur)})", self.steps)
        for name in ("lr_rotation", "lr_translation", "lr_focal", "lr_centre", "lr_depth"):
            if not getattr(self, name) > 0:
                raise bad_field("RefineConfig", name, "> 0", getattr(self, name))
        if not self.smoothness >= 0:
            raise bad_field("RefineConfig", "smoothness", ">= 0", self.smoothness)
        if not 0 <= self.flatten < 0.5:
            raise bad_field("RefineConfig", "flatten", "in [0, 0.5) of the image width",
                            self.flatten)
        if not 0 <= self.occlusion < 1:
            raise bad_field("RefineConfig", "occlusion", "in [0, 1)", self.occlusion)
        if int(self.rounds) != self.rounds or self.rounds < 1:
            raise bad_field("RefineConfig", "rounds", "an integer >= 1", self.rounds)

    def replace(self, **kw) -> "RefineConfig":
        return dataclasses.replace(self, **kw)


# ------------------------------------------------------------------------------ parameters


def initial_parameters(rig: Rig, log_inv: Array, intrinsics: bool = False) -> dict:
    """Zero pose (and intrinsics) updates for ``rig`` and the frames' ``log_inv`` (F, H, W):
    ``rotation`` and ``translation`` (N - 1, 3) for cameras 1.. (camera 0 is the gauge),
    ``focal`` (N,) and ``centre`` (N, 2) with ``intrinsics``, ``log_inv``."""
    n = rig.num_cameras
    dtype = rig.translations.dtype
    params = {"rotation": jnp.zeros((n - 1, 3), dtype), "translation": jnp.zeros((n - 1, 3), dtype),
              "log_inv": jnp.asarray(log_inv, dtype)}
    if intrinsics:
        params["focal"] = jnp.zeros((n,), dtype)
        params["centre"] = jnp.zeros((n, 2), dtype)
    return params


def apply_calibration(rig: Rig, params: dict) -> Rig:
    """``rig`` with the pose (and intrinsics) updates of ``params`` applied, under the gauge of
    the module docstring: camera 0 unchanged, the camera 0-1 distance unchanged."""
    n = rig.num_cameras
    dtype = rig.translations.dtype
    w = jnp.concatenate([jnp.zeros((1, 3), dtype), params["rotation"].astype(dtype)], 0)
    dt = jnp.concatenate([jnp.zeros((1, 3), dtype), params["translation"].astype(dtype)], 0)
    rotations = rig.rotations @ axis_angle_to_matrix(w)
    translations = rig.translations + dt
    if n > 1:
        # Camera 1 moves on the sphere around camera 0 through its initial position.
        t0 = rig.translations[0]
        arm = rig.translations[1] - t0
        moved = arm + dt[1]
        radius = jnp.sqrt(jnp.sum(arm * arm))
        t1 = t0 + radius * moved / jnp.sqrt(jnp.maximum(jnp.sum(moved * moved), 1e-30))
        translations = translations.at[1].set(t1)
    cams = rig.cameras
    if "focal" in params:
        scale = jnp.exp(params["focal"].astype(dtype))
        shift = params["centre"].astype(dtype)
        cams = tuple(dataclasses.replace(c, fx=c.fx * scale[i], fy=c.fy * scale[i],
                                         cx=c.cx + shift[i, 0], cy=c.cy + shift[i, 1])
                     for i, c in enumerate(rig.cameras))
    return rig.replace(cameras=cams, rotations=rotations, translations=translations)


# ------------------------------------------------------------------------------ images


def prepare_images(images: Array, masks: Array, sigma, radius: int, flatten_sigma=0.0,
                   flatten_radius: int = 0) -> Array:
    """Gain-normalised, flattened, blurred images of one frame: (N, h, w, 3) in [0, 1] and
    masks (N, h, w) -> (N, h, w, 3).

    Every camera and channel is scaled so that its mean over the valid pixels equals the
    frame's mean over all cameras (exposure and white balance are not disagreement). With
    ``flatten_radius`` > 0 every pixel is then divided by its neighbourhood's mean (a masked
    Gaussian of ``flatten_sigma`` pixels) and scaled back to that frame mean: a smooth
    multiplicative field, above all a lens's vignetting (up to a third darker at the rim, and
    different per camera), is not disagreement either; left in, it pulls the poses towards
    where the cameras' fall-offs agree. The blur (``sigma`` pixels, ``radius`` taps static) is
    normalised by the blurred mask, so the rig's body and the black outside the lens do not
    bleed into the valid pixels.
    """
    m = masks.astype(images.dtype)[..., None]
    means = jnp.sum(images * m, (1, 2)) / jnp.maximum(jnp.sum(m, (1, 2)), 1.0)       # (N, 3)
    target = jnp.mean(means, 0)
    gained = images * (target / jnp.maximum(means, 1e-3))[:, None, None, :]
    if flatten_radius > 0:
        wide = jax.vmap(lambda x: gaussian_blur(x, flatten_sigma, flatten_radius))
        local = wide(gained * m) / jnp.maximum(wide(m), 1e-3)
        # The floor keeps dark corners from being amplified into noise.
        gained = gained / jnp.maximum(local, 0.05 * target) * target
    blur = jax.vmap(lambda x: gaussian_blur(x, sigma, radius))
    num = blur(gained * m)
    den = blur(m)
    return jnp.where(den > 1e-3, num / jnp.maximum(den, 1e-3), 0.0) * m


def blur_radius(sigma: float) -> int:
    """Taps either side of a Gaussian of ``sigma`` pixels (a static size)."""
    return max(1, int(math.ceil(3.0 * float(sigma))))


# ------------------------------------------------------------------------------ loss


def frame_samples(rig: Rig, images: Array, masks: Array, log_inv: Array,
                  pano: Panorama, occlusion: float = OCCLUSION_MARGIN) -> tuple[Array, Array]:
    """Every camera's view of one frame's panorama points ``reference + ray / inv``.

    Args as :func:`frame_terms`. Returns ``(colours, weights)``: (N, H, W, 3) each camera's
    bilinear sample of its prepared image, and (N, H, W) its sampled mask times whether the
    point projects inside its image times, with ``occlusion`` > 0, whether no nearer panorama
    point hides it from the camera (:func:`gijax.geometry.visibility.visible_from` with that
    margin, bins of the panorama's width; 0 = not seen)."""
    dtype = images.dtype
    rays = panorama_rays(rig, pano, dtype)                                   # (H, W, 3)
    lo, hi = math.log(1.0 / MAX_DISTANCE), math.log(1.0 / MIN_DISTANCE)
    dist = jnp.exp(-jnp.clip(log_inv.astype(dtype), lo, hi))
    pts = rig.reference.astype(dtype) + dist[..., None] * rays               # (H, W, 3)
    cams = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *rig.cameras)
    packed = jnp.concatenate([images, masks[..., None].astype(dtype)], -1)

    def one_camera(cam, rot, trans, img):
        pc = (pts - trans.astype(dtype)) @ rot.astype(dtype)
        px, ok = cam_lib.project(cam, pc)
        vals, inside = bilinear_sample(img, px, ok)
        weight = vals[..., 3] * inside.astype(dtype)
        if occlusion > 0:
            weight = weight * visible_from(pts, trans, pano.width, occlusion)
        return vals[..., :3], weight

    return jax.vmap(one_camera)(cams, rig.rotations, rig.translations, packed)


def frame_terms(rig: Rig, images: Array, masks: Array, log_inv: Array,
                pano: Panorama, edge_scale: float = 0.05,
                guide: Optional[Array] = None, occlusion: float = OCCLUSION_MARGIN) -> dict:
    """One frame's photometric terms at the calibration of ``rig``.

    Args:
      rig: the rig (cameras of one model and size).
      images: (N, h, w, 3) prepared images (:func:`prepare_images`); ``masks`` (N, h, w).
      log_inv: (H, W) log inverse distance (1/m) on ``pano`` (the rig's panorama frame).
      pano: the panorama (static); ``edge_scale``: see :class:`RefineConfig`.
      guide: (H, W, 3) the panorama colour the smoothness's edges are found in, or None for
        this call's own (``colour``). :func:`refine_rig` passes the colour of the calibration
        at the start of each blur level: with the edges inside the gradient, the smoothness
        would pull the poses towards sharper (misaligned) edges.
      occlusion: see :class:`RefineConfig` (static).

    Returns a dict of scalars ``data`` (mean dispersion over compared points), ``smooth``
    (edge-aware total variation of ``log_inv``), ``overlap`` (fraction of panorama points
    compared), and the maps ``dispersion`` and ``weight`` (total camera weight) (H, W) and
    ``colour`` (H, W, 3, the cameras' weighted mean).
    """
    dtype = images.dtype
    cols, wts = frame_samples(rig, images, masks, log_inv, pano, occlusion)
    dispersion, total = view_dispersion(cols, wts)
    seen = (total >= SEEN_WEIGHT).astype(dtype)
    count = jnp.maximum(jnp.sum(seen), 1.0)
    data = jnp.sum(dispersion * seen) / count
    # Edge-aware smoothness: neighbours whose colour differs are allowed to differ.
    colour = jnp.sum(cols * wts[..., None], 0) / jnp.maximum(total, 1e-6)[..., None]
    edges_in = colour if guide is None else guide.astype(dtype)
    smooth = 0.0
    for axis, wrap in ((0, False), (1, True)):
        if wrap:
            d_inv = jnp.roll(log_inv, -1, axis) - log_inv
            d_col = jnp.roll(edges_in, -1, axis) - edges_in
            both = seen * jnp.roll(seen, -1, axis)
        else:
            d_inv = jnp.diff(log_inv, axis=axis)
            d_col = jnp.diff(edges_in, axis=axis)
            both = seen[1:] * seen[:-1]
        edge = jnp.exp(-jnp.sqrt(jnp.sum(d_col * d_col, -1) + 1e-12) / edge_scale)
        tv = jnp.sqrt(d_inv * d_inv + 1e-6)
        smooth = smooth + jnp.sum(tv * edge * both) / count
    return dict(data=data, smooth=smooth, overlap=jnp.mean(seen), dispersion=dispersion,
                weight=total, colour=colour)


def refinement_loss(params: dict, rig: Rig, images: Array, masks: Array, pano: Panorama,
                    smoothness: float = 0.02, edge_scale: float = 0.05,
                    guides: Optional[Array] = None,
                    occlusion: float = OCCLUSION_MARGIN) -> tuple[Array, dict]:
    """The objective over frames: mean data term + ``smoothness`` x mean smoothness.

    ``params`` as :func:`initial_parameters` (``log_inv`` (F, H, W)); ``images`` (F, N, h, w, 3)
    prepared, ``masks`` (F, N, h, w); ``guides`` (F, H, W, 3) or None (see
    :func:`frame_terms`); ``occlusion`` see :class:`RefineConfig` (static). Returns
    ``(loss, {'data', 'smooth'})``.
    """
    refined = apply_calibration(rig, params)
    if guides is None:
        terms = jax.vmap(lambda im, m, li: frame_terms(refined, im, m, li, pano, edge_scale,
                                                       None, occlusion))(
            images, masks, params["log_inv"])
    else:
        terms = jax.vmap(lambda im, m, li, g: frame_terms(refined, im, m, li, pano, edge_scale,
                                                          g, occlusion))(
            images, masks, params["log_inv"], guides)
    data = jnp.mean(terms["data"])
    smooth = jnp.mean(terms["smooth"])
    return data + smoothness * smooth, {"data": data, "smooth": smooth}


# ------------------------------------------------------------------------------ the loop


@dataclasses.dataclass
class RefineResult:
    """``rig`` refined (the input's names, masks, panorama frame), ``initial`` the input rig,
    ``history`` of ``{'step', 'round', 'level', 'loss', 'data'}`` (steps counted across
    rounds), ``loss_before`` / ``loss_after`` (the photometric data term at the finest blur,
    initial calibration with the RTSS distances vs refined calibration with refined distances,
    after the last round), ``moved`` (:func:`pose_change`), ``frames`` (per frame ``texture``
    per camera and ``overlap`` of the first round, see :func:`frame_texture`,
    :func:`frame_overlap`), ``inv_distance`` (F, H, W) refined, and ``round_moves``: for each
    round after the first, :func:`pose_change` from the previous round's calibration (moves
    that still shrink say another round may help; moves near zero, that the rounds have
    settled)."""

    rig: Rig
    initial: Rig
    history: list
    loss_before: float
    loss_after: float
    moved: dict
    frames: list
    inv_distance: np.ndarray
    round_moves: list = dataclasses.field(default_factory=list)


def frame_texture(images: np.ndarray, masks: np.ndarray) -> list:
    """Per camera the intensity contrast of one frame (NumPy report): the standard deviation
    of the grey level (in [0, 1]) over the camera's valid pixels, 0 when it has none."""
    grey = np.asarray(images, np.float64).mean(-1)
    m = np.asarray(masks) > 0.5
    return [float(g[k].std()) if k.any() else 0.0 for g, k in zip(grey, m)]


def frame_overlap(rig: Rig, images: np.ndarray, masks: np.ndarray, log_inv: np.ndarray,
                  pano: Panorama, occlusion: float = OCCLUSION_MARGIN) -> float:
    """The fraction of one frame's panorama that two cameras see at ``log_inv`` (a concrete
    report of :func:`frame_terms`' ``overlap``; ``occlusion`` see :class:`RefineConfig`)."""
    terms = _frame_terms_jit(rig, jnp.asarray(images, jnp.float32),
                             jnp.asarray(masks, jnp.float32), jnp.asarray(log_inv, jnp.float32),
                             pano, float(occlusion))
    return float(terms["overlap"])


@functools.partial(jax.jit, static_argnames=("pano", "occlusion"))
def _frame_terms_jit(rig, images, masks, log_inv, pano, occlusion):
    return frame_terms(rig, images, masks, log_inv, pano, occlusion=occlusion)


def check_texture(texture: Sequence[list], names: Sequence[str], labels: Sequence[str],
                  config: RefineConfig) -> None:
    """ValueError (one line: which frame and camera, the measure, the threshold) for the first
    camera of a frame whose :func:`frame_texture` is below ``config.min_texture``."""
    for label, per_camera in zip(labels, texture):
        for name, tex in zip(names, per_camera):
            if not tex >= config.min_texture:
                raise ValueError(f"frame {label}: camera {name} has intensity contrast "
                                 f"{tex:.4f} (std of the grey level over its valid pixels), "
                                 f"below {config.min_texture}: too little texture to refine on")


def check_overlap(overlap: Sequence[float], labels: Sequence[str], config: RefineConfig) -> None:
    """ValueError (one line) for the first frame whose :func:`frame_overlap` is below
    ``config.min_overlap``."""
    for label, value in zip(labels, overlap):
        if not value >= config.min_overlap:
            raise ValueError(f"frame {label}: {value * 100:.1f}% of the panorama is seen by two "
                             f"cameras (at the initial distances), below "
                             f"{config.min_overlap * 100:.1f}%: too little overlap to refine on")


def initial_inverse_distance(rig: Rig, images: np.ndarray, masks: np.ndarray,
                             pano: Panorama, match_size: Optional[int] = None) -> np.ndarray:
    """The classical baseline's inverse distance (H, W) for one frame at ``rig``'s
    calibration, holes filled with the median of the valid pixels (NumPy, an edge)."""
    from gijax.baseline.rtss import get_rtss_preset, preset_candidates, rtss_predict

    width = min(c.width for c in rig.cameras)
    config = get_rtss_preset("RS-E32").replace(
        match_size=int(match_size or min(256, width)), d_min=0.5, d_max=100.0)
    out = rtss_predict(rig, jnp.asarray(images, jnp.float32), jnp.asarray(masks, jnp.float32),
                       preset_candidates(rig, config), pano, config)
    inv = np.asarray(out["inv_distance"], np.float64)
    ok = np.asarray(out["valid"]) & usable_label(inv)
    fill = float(np.median(inv[ok])) if ok.any() else 1.0 / 5.0
    return np.where(ok, inv, fill)


_STEPS: dict = {}


def _step_fn(pano: Panorama, config: RefineConfig):
    """The jitted Adam step, one per (panorama, step settings) in a process (keyed on what
    the step reads, so runs differing in steps, rounds or checks share it)."""
    key = (pano, config.lr_rotation, config.lr_translation, config.lr_focal, config.lr_centre,
           config.lr_depth, config.smoothness, config.edge_scale, config.occlusion)
    if key not in _STEPS:
        tx = optax.scale_by_adam()
        rates = {"rotation": config.lr_rotation, "translation": config.lr_translation,
                 "focal": config.lr_focal, "centre": config.lr_centre,
                 "log_inv": config.lr_depth}

        @jax.jit
        def step(params, opt_state, scale, rig, images, masks, guides):
            def loss_fn(p):
                return refinement_loss(p, rig, images, masks, pano, config.smoothness,
                                       config.edge_scale, guides, config.occlusion)

            (loss, aux), grad = jax.value_and_grad(loss_fn, has_aux=True)(params)
            updates, opt_state = tx.update(grad, opt_state, params)
            params = {k: params[k] - scale * rates[k] * updates[k] for k in params}
            return params, opt_state, loss, aux["data"]

        _STEPS[key] = (tx, step)
    return _STEPS[key]


def refine_rig(rig: Rig, images: np.ndarray, masks: Optional[np.ndarray] = None,
               config: RefineConfig = RefineConfig(), labels: Optional[Sequence[str]] = None,
               initial_inv: Optional[np.ndarray] = None, progress: bool = True,
               log: Optional[Callable[[str], None]] = None) -> RefineResult:
    """Refine ``rig``'s calibration from unlabeled frames (the edge: checks, RTSS start, loop).

    Args:
      rig: the rig at the images' size (cameras of one model and size).
      images: (F, N, h, w, 3) frames, uint8 or float in [0, 1].
      masks: (F, N, h, w), 1 = valid, or None for the rig's own masks.
      config: :class:`RefineConfig`.
      labels: one name per frame for messages (default its index).
      initial_inv: (F, H, W) starting inverse distances instead of the classical baseline's
        (for the first round; later rounds start from the baseline's, see
        :attr:`RefineConfig.rounds`).
      progress, log: progress bar, and a callback for one-line notes.

    Raises ValueError (one line) for frames with too little texture or overlap.
    """
    say = log or (lambda _line: None)
    result = _refine_round(rig, images, masks, config, labels, initial_inv, progress, 0)
    for k in range(1, int(config.rounds)):
        say(f"round {k}: photometric loss {result.loss_before:.5f} -> {result.loss_after:.5f}; "
            f"restarting from the classical baseline's distances at the refined calibration")
        nxt = _refine_round(result.rig, images, masks, config, labels, None, progress, k)
        history = result.history + [dict(h, step=h["step"] + len(result.history))
                                    for h in nxt.history]
        step_move = pose_change(result.rig, nxt.rig)
        say(round_move_line(k + 1, step_move))
        result = RefineResult(nxt.rig, rig, history, result.loss_before, nxt.loss_after,
                              pose_change(rig, nxt.rig), result.frames, nxt.inv_distance,
                              result.round_moves + [step_move])
    say(f"photometric loss {result.loss_before:.5f} -> {result.loss_after:.5f}")
    return result


def _refine_round(rig: Rig, images: np.ndarray, masks: Optional[np.ndarray],
                  config: RefineConfig, labels: Optional[Sequence[str]],
                  initial_inv: Optional[np.ndarray], progress: bool,
                  round_index: int) -> RefineResult:
    """One round of :func:`refine_rig`: checks, the starting distances, the coarse-to-fine
    Adam schedule from ``rig``'s calibration."""
    from tqdm import tqdm

    of_rounds = f", round {round_index + 1} of {config.rounds}" if config.rounds > 1 else ""
    images = np.asarray(images)
    if images.ndim != 5 or images.shape[1] != rig.num_cameras or images.shape[-1] != 3:
        raise ValueError(f"images must have shape (frames, Ncam={rig.num_cameras}, h, w, 3); "
                         f"found {images.shape}")
    if rig.num_cameras < 2:
        raise ValueError(f"refinement needs at least 2 cameras; the rig has {rig.num_cameras}")
    if not is_homogeneous(rig):
        raise ValueError("refinement needs cameras of one model and image size (and masks "
                         "either all set or all unset)")
    cam = rig.cameras[0]
    if images.shape[2:4] != (cam.height, cam.width):
        raise ValueError(f"images are {images.shape[2]}x{images.shape[3]} but the rig's cameras "
                         f"are {cam.height}x{cam.width}")
    if images.dtype == np.uint8:
        images = images.astype(np.float32) / 255.0
    images = images.astype(np.float32)
    rig_masks = np.stack([np.ones((c.height, c.width), np.float32) if m is None
                          else np.asarray(m, np.float32) for c, m in zip(rig.cameras, rig.masks)])
    masks = (np.broadcast_to(rig_masks, images.shape[:4]) if masks is None
             else np.asarray(masks, np.float32) * rig_masks)
    masks = (masks > 0.5).astype(np.float32)
    labels = [str(i) for i in range(len(images))] if labels is None else list(labels)
    texture = [frame_texture(im, m) for im, m in zip(images, masks)]
    check_texture(texture, rig.names, labels, config)
    choice = choose_panorama(rig)
    pano = refine_panorama(rig, config)
    work = with_panorama_rotation(rig, choice.rotation)
    work = work.replace(rotations=jnp.asarray(work.rotations, jnp.float32),
                        translations=jnp.asarray(work.translations, jnp.float32))

    if initial_inv is None:
        inv0 = []
        for f in tqdm(range(len(images)), desc=f"refine: initial distances (RTSS){of_rounds}",
                      unit="frame", disable=not progress):
            inv0.append(initial_inverse_distance(work, images[f], masks[f], pano))
        initial_inv = np.stack(inv0)
    initial_inv = np.asarray(initial_inv, np.float64)
    if initial_inv.shape != (len(images), *pano.shape):
        raise ValueError(f"initial inverse distances must have shape "
                         f"{(len(images), *pano.shape)}; found {initial_inv.shape}")
    log_inv0 = np.log(np.clip(initial_inv, 1.0 / MAX_DISTANCE, 1.0 / MIN_DISTANCE))
    finest = config.blur[-1]
    fine_images = _prepared(images, masks, finest, config.flatten)
    overlap = [frame_overlap(work, images[f], masks[f], log_inv0[f], pano, config.occlusion)
               for f in range(len(images))]
    check_overlap(overlap, labels, config)
    measures = [{"texture": t, "overlap": o} for t, o in zip(texture, overlap)]

    params = initial_parameters(work, jnp.asarray(log_inv0, jnp.float32), config.intrinsics)
    tx, step = _step_fn(pano, config)
    opt = tx.init(params)
    jmasks = jnp.asarray(masks)
    loss_before = _data_term(work, params, fine_images, jmasks, pano, config.occlusion)
    history = []
    per_level = [config.steps // len(config.blur)] * len(config.blur)
    per_level[-1] += config.steps - sum(per_level)
    done = 0
    with tqdm(total=config.steps, desc=f"refine calibration{of_rounds}", unit="step",
              disable=not progress) as bar:
        for level, (sigma, count) in enumerate(zip(config.blur, per_level)):
            level_images = (fine_images if sigma == finest
                            else _prepared(images, masks, sigma, config.flatten))
            guides = _guides(work, params, level_images, jmasks, pano, config.occlusion)
            for _ in range(count):
                frac = done / max(config.steps - 1, 1)
                scale = config.lr_floor + (1 - config.lr_floor) * 0.5 * (1 + math.cos(math.pi * frac))
                params, opt, loss, data = step(params, opt, jnp.float32(scale), work,
                                               level_images, jmasks, guides)
                loss, data = float(loss), float(data)
                if not math.isfinite(loss):
                    raise FloatingPointError(f"refinement loss is {loss} at step {done}")
                history.append({"step": done, "round": round_index, "level": level,
                                "loss": loss, "data": data})
                bar.set_postfix(loss=f"{loss:.4f}", blur=f"{sigma:g}")
                bar.update(1)
                done += 1
    loss_after = _data_term(work, params, fine_images, jmasks, pano, config.occlusion)
    refined = apply_calibration(work, jax.device_get(params))
    out_rig = _concrete_rig(rig, refined, config.intrinsics)
    return RefineResult(out_rig, rig, history, loss_before, loss_after, pose_change(rig, out_rig),
                        measures, np.exp(np.asarray(params["log_inv"], np.float64)))


def refine_panorama(rig: Rig, config: RefineConfig = RefineConfig()) -> Panorama:
    """The panorama the distance maps of :func:`refine_rig` live on: the coverage
    :func:`gijax.geometry.panorama_frame.choose_panorama` picks for ``rig`` at
    ``config.pano_hw`` (a static panorama from concrete poses)."""
    return panorama_of(choose_panorama(rig).coverage, config.pano_hw)


def _prepared(images: np.ndarray, masks: np.ndarray, sigma: float, flatten: float) -> Array:
    flatten_sigma = flatten * images.shape[-2]
    fn = _prepare_jit(blur_radius(sigma), blur_radius(flatten_sigma) if flatten > 0 else 0)
    return jnp.stack([fn(jnp.asarray(im), jnp.asarray(m), jnp.float32(sigma),
                         jnp.float32(flatten_sigma)) for im, m in zip(images, masks)])


@functools.lru_cache(maxsize=None)
def _prepare_jit(radius: int, flatten_radius: int):
    return jax.jit(lambda im, m, s, fs: prepare_images(im, m, s, radius, fs, flatten_radius))


def _guides(rig: Rig, params: dict, images: Array, masks: Array, pano: Panorama,
            occlusion: float) -> Array:
    """Every frame's panorama colour at the current calibration (the smoothness's edges)."""
    refined = apply_calibration(rig, params)
    return jnp.stack([_frame_terms_jit(refined, images[f], masks[f], params["log_inv"][f],
                                       pano, float(occlusion))["colour"]
                      for f in range(images.shape[0])])


def _data_term(rig: Rig, params: dict, images: Array, masks: Array, pano: Panorama,
               occlusion: float) -> float:
    refined = apply_calibration(rig, params)
    return float(np.mean([float(_frame_terms_jit(refined, images[f], masks[f],
                                                 params["log_inv"][f], pano,
                                                 float(occlusion))["data"])
                          for f in range(images.shape[0])]))


def _concrete_rig(original: Rig, refined: Rig, intrinsics: bool) -> Rig:
    """The original rig (names, masks, occluder, panorama frame, dtypes) with the refined
    poses, and intrinsics where refined."""
    dtype = original.translations.dtype
    cams = original.cameras
    if intrinsics:
        cams = tuple(dataclasses.replace(
            c, **{k: jnp.asarray(getattr(r, k), jnp.asarray(getattr(c, k)).dtype)
                  for k in ("fx", "fy", "cx", "cy")})
            for c, r in zip(original.cameras, refined.cameras))
    rot = np.asarray(refined.rotations, np.float64)
    # Re-orthonormalise in float64 (float32 steps leave |R^T R - I| at a few ulps).
    u, _, vt = np.linalg.svd(rot)
    rot = u @ vt
    return original.replace(cameras=cams, rotations=jnp.asarray(rot, dtype),
                            translations=jnp.asarray(np.asarray(refined.translations), dtype))


def transfer_refinement(full: Rig, before: Rig, after: Rig) -> Rig:
    """``full`` (the rig at its calibrated image size) with the refinement that took ``before``
    to ``after`` (the same rig at a working size, e.g. :func:`gijax.geometry.rig.scale_rig`):
    the poses of ``after``; focal lengths scaled by after / before and principal points shifted
    by the working-size shift times the size ratio (NumPy edge, a concrete rig)."""
    cams = []
    for c, b, a in zip(full.cameras, before.cameras, after.cameras):
        ratio = c.width / b.width
        dtype = jnp.asarray(c.fx).dtype
        vals = {k: float(getattr(c, k)) * float(getattr(a, k)) / float(getattr(b, k))
                for k in ("fx", "fy")}
        vals.update({k: float(getattr(c, k)) + ratio * (float(getattr(a, k)) - float(getattr(b, k)))
                     for k in ("cx", "cy")})
        cams.append(dataclasses.replace(c, **{k: jnp.asarray(v, dtype) for k, v in vals.items()}))
    return full.replace(cameras=tuple(cams),
                        rotations=jnp.asarray(after.rotations, full.rotations.dtype),
                        translations=jnp.asarray(after.translations, full.translations.dtype))


# ------------------------------------------------------------------------------ reports


def _rotation_angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle of each ``a_i^T b_i`` in degrees, as ``atan2(2 sin, 2 cos)``: the sine from the
    antisymmetric part keeps small angles exact. ``arccos`` of the trace cannot tell angles
    under about 0.02 degree from zero in float32 poses (the trace is 3 to within its rounding)."""
    rel = np.einsum("nji,njk->nik", np.asarray(a, np.float64), np.asarray(b, np.float64))
    two_sin = np.linalg.norm(np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0],
                                       rel[:, 1, 0] - rel[:, 0, 1]], -1), axis=-1)
    two_cos = np.trace(rel, axis1=1, axis2=2) - 1.0
    return np.degrees(np.arctan2(two_sin, two_cos))


# The working width of a refinement (pixels): the bundled model's and the cpu-scale experiments'
# 256 px images (1024 px cameras at 0.25). Refining a 256 px rig at a quarter of its size (64 px,
# under a degree a pixel for the narrow rings that need the correction) let cameras wander by
# several times their spacing on the documented example rig.
REFINE_WIDTH = 256


def refine_scale(width: int) -> float:
    """The default working scale of a ``width`` px camera: the factor that makes it
    :data:`REFINE_WIDTH` wide, never enlarging (0.25 for 1024 px, 1 for 256 px or less)."""
    return min(1.0, REFINE_WIDTH / float(width))


def implausible_moves(rig: Rig, moved: dict, spacing_share: float = 0.5,
                      max_deg: float = 5.0) -> list:
    """One line per camera whose refined pose moved more than ``spacing_share`` of its distance
    to the nearest other camera or more than ``max_deg`` degrees (``moved``: the
    ``rotation_deg`` / ``translation_mm`` lists of :func:`pose_change`). A calibration that
    is off by that much is not what refinement corrects; far more often the frames do not
    constrain that camera (little overlap or texture at the working size)."""
    trans = np.asarray(rig.translations, np.float64)
    lines = []
    for i, name in enumerate(rig.names):
        others = np.delete(trans, i, axis=0)
        near_mm = 1000.0 * float(np.min(np.linalg.norm(others - trans[i], axis=-1))) \
            if len(others) else math.inf
        mm, deg = float(moved["translation_mm"][i]), float(moved["rotation_deg"][i])
        if mm > spacing_share * near_mm or deg > max_deg:
            lines.append(f"{name} moved {deg:.2f} deg and {mm:.1f} mm ({mm / near_mm:.1f}x its "
                         f"{near_mm:.0f} mm to the nearest camera): the frames likely do not "
                         f"constrain it; check it before use (more frames, more texture, a "
                         f"larger --scale)")
    return lines


def round_move_line(round_number: int, move: dict) -> str:
    """One line of text: how far round ``round_number`` (counted from 1) moved the cameras
    from the previous round's calibration (``move``: a :func:`pose_change` report)."""
    return (f"round {round_number} moved the cameras by at most "
            f"{max(move['rotation_deg']):.4f} deg and {max(move['translation_mm']):.2f} mm from "
            f"round {round_number - 1}'s calibration")


def pose_change(before: Rig, after: Rig) -> dict:
    """Per camera how far ``after`` moved from ``before`` (NumPy report): ``rotation_deg`` (the
    angle of R_before^T R_after) and ``translation_mm`` (camera centre distance)."""
    ra, rb = (np.asarray(r.rotations, np.float64) for r in (before, after))
    ta, tb = (np.asarray(r.translations, np.float64) for r in (before, after))
    return {"rotation_deg": _rotation_angles_deg(ra, rb).tolist(),
            "translation_mm": (np.linalg.norm(tb - ta, axis=-1) * 1e3).tolist()}


def _gauge_aligned_poses(rig: Rig, reference: Rig) -> tuple[np.ndarray, np.ndarray, float]:
    """``rig``'s rotations and translations in ``reference``'s gauge, float64, and the scale
    (see :func:`align_gauge`)."""
    ra, rt = (np.asarray(r.rotations, np.float64) for r in (rig, reference))
    ta, tt = (np.asarray(r.translations, np.float64) for r in (rig, reference))
    # The rigid motion g with g(camera 0 of rig) = camera 0 of reference.
    g = rt[0] @ ra[0].T
    rot = np.einsum("ij,njk->nik", g, ra)
    trans = (ta - ta[0]) @ g.T
    scale = 1.0
    if len(ta) > 1:
        scale = float(np.linalg.norm(tt[1] - tt[0]) / max(np.linalg.norm(trans[1]), 1e-12))
    return rot, tt[0] + scale * trans, scale


def align_gauge(rig: Rig, reference: Rig) -> tuple[Rig, float]:
    """``rig`` brought into ``reference``'s gauge (NumPy, concrete poses): the rigid motion
    that puts its camera 0 on ``reference``'s camera 0, then the scale about camera 0 that makes
    its camera 0-1 distance ``reference``'s. Returns (that rig, the scale applied; 1 for one
    camera). What images cannot tell apart is removed: a rig refined from images, aligned to
    the true one, differs from it only by what the images got wrong."""
    rot, trans, scale = _gauge_aligned_poses(rig, reference)
    return rig.replace(rotations=jnp.asarray(rot, rig.rotations.dtype),
                       translations=jnp.asarray(trans, rig.translations.dtype)), scale


def gauge_aligned_errors(rig: Rig, truth: Rig) -> dict:
    """Pose errors of ``rig`` against ``truth`` modulo the refinement's gauge (NumPy report):
    ``rig`` is first brought into ``truth``'s gauge (:func:`align_gauge`, in float64). Returns
    per camera ``rotation_deg`` and ``translation_mm`` as :func:`pose_change`, and the
    ``scale`` applied."""
    rot, trans, scale = _gauge_aligned_poses(rig, truth)
    rt = np.asarray(truth.rotations, np.float64)
    tt = np.asarray(truth.translations, np.float64)
    return {"rotation_deg": _rotation_angles_deg(rot, rt).tolist(),
            "translation_mm": (np.linalg.norm(trans - tt, axis=-1) * 1e3).tolist(),
            "scale": scale}
