"""How well a set of unlabeled frames constrains each camera's pose: the curvature of the
refinement's objective in the pose parameters once the distance maps have re-fitted.

A translation can hide in the distances: on far scenes, moving a camera and bending the
distance maps together leaves the photometric agreement almost unchanged, so the refinement's
answer along that direction is set by noise, not by the frames. The measure here is the one
that captures it, the Schur complement of the objective's curvature in the pose parameters,

    S = H_pp - H_pd H_dd^-1 H_dp,

``p`` the pose updates of :func:`gijax.calibrate.refine.initial_parameters` (rotation vectors
and translations of cameras 1..N-1) and ``d`` the frames' log inverse distances. ``H`` is the
Gauss-Newton matrix of the data term (positive semi-definite, so ``S`` is too; the full
Hessian is indefinite away from a minimum) plus the smoothness's exact Hessian. ``H_dd`` is
taken per panorama point (its diagonal): the data term couples no two points, and the
smoothness, which couples neighbours, is weak at the refinement's settings; neglecting it
lets the distances absorb a little more than they can, so ``S`` errs towards "weakly
constrained". The diagonal is exact and matrix-free: the smoothness couples only the four
neighbours of a point (columns wrap), so one Hessian-vector product per colour of a
colouring in which neighbours differ reads it.

From ``S`` a predicted standard deviation: the independent-points model of least squares,
``Cov = (2 L / M) S^-1`` with ``L`` the data term and ``M`` the number of compared points,
restricted to the gauge (camera 1's translation along its arm from camera 0 is not a
parameter of the rig: see :data:`gijax.calibrate.refine.GAUGE`). Neighbouring samples of
blurred images are not independent, so these figures are a lower bound on the real spread: they
rank cameras and frame sets, and a large one says the frames do not pin that pose down. They
measure information, not bias: a systematic pull (an unmodelled vignetting, occlusions) moves
the answer by more than they say.

Pure and traceable: :func:`pose_information`. The report at the edge: :func:`pose_constraint`
(concrete frames, NumPy out), :func:`constraint_report`, :func:`weak_constraint_lines` and
:func:`constraint_lines`.
"""

from __future__ import annotations

import functools
import math
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from gijax.calibrate.refine import (MAX_DISTANCE, MIN_DISTANCE, SEEN_WEIGHT, RefineConfig,
                                    _frame_terms_jit, _prepared, apply_calibration,
                                    frame_samples, initial_parameters, refine_panorama,
                                    refinement_loss)
from gijax.geometry.panorama import Panorama
from gijax.geometry.panorama_frame import choose_panorama, with_panorama_rotation
from gijax.geometry.rig import Rig
from gijax.geometry.visibility import OCCLUSION_MARGIN
from gijax.sweep.consistency import view_dispersion

Array = jax.Array

POSE_KEYS = ("rotation", "translation")


def neighbour_colouring(hw: tuple) -> np.ndarray:
    """(H, W) integer colours in which no two 4-neighbours share a colour, columns wrapping
    (the panorama's longitude): a checkerboard, and for an odd W its last column in two more
    colours (NumPy constant of a static size)."""
    h, w = hw
    i, j = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    colours = (i + j) % 2
    if w % 2:
        colours = np.where(j == w - 1, 2 + i % 2, colours)
    return colours


def pose_information(params: dict, rig: Rig, images: Array, masks: Array, pano: Panorama,
                     smoothness: float = 0.02, edge_scale: float = 0.05,
                     guides: Optional[Array] = None, occlusion: float = OCCLUSION_MARGIN) -> dict:
    """The refinement objective's Gauss-Newton curvature in the pose parameters (pure; jit
    with ``pano`` static).

    Gauss-Newton: per compared point, ``J^T C J`` with ``J`` the derivative of the cameras'
    colour samples (:func:`gijax.calibrate.refine.frame_samples`) and ``C`` the Hessian of the
    point's dispersion in those samples (convex: positive semi-definite), the mask weights
    held; the second derivatives of the projections and samplers, which average out at a
    minimum and make the full Hessian indefinite away from one, are left out. The smoothness
    (a function of the distances alone) enters the distances' block exactly.

    Args:
      params: as :func:`gijax.calibrate.refine.initial_parameters` (poses only), at the point
        to measure (typically zero updates about the refined rig, with its distance maps).
      rig, images, masks, pano, smoothness, edge_scale: as
        :func:`gijax.calibrate.refine.refinement_loss`.
      guides: (F, H, W, 3) the smoothness's edge colours, held fixed (see
        :func:`gijax.calibrate.refine.frame_terms`); None for the objective's own, which
        couples more than neighbours, so the distances' diagonal is then approximate.
      occlusion: as :class:`gijax.calibrate.refine.RefineConfig` (static); which points a
        camera sees is held (a step function of the distances, without derivative).

    Returns a dict: ``pose`` (P, P) the curvature in the pose parameters with the distances
    held, ``marginal`` (P, P) the Schur complement with the distances re-fitted per point,
    ``distance`` (F, H, W) the distances' diagonal, ``data`` the data term, ``points`` the
    compared panorama points summed over frames. P = 6 (N - 1), ordered rotation vectors then
    translations, each camera 1..N-1 in turn.
    """
    shapes = [params[k].shape for k in POSE_KEYS]
    sizes = [int(np.prod(s)) for s in shapes]
    flat = jnp.concatenate([params[k].reshape(-1) for k in POSE_KEYS])
    log_inv = params["log_inv"]
    dtype = log_inv.dtype

    def unflatten(v):
        parts = jnp.split(v, np.cumsum(sizes)[:-1])
        return dict(params, **{k: p.reshape(s) for k, p, s in zip(POSE_KEYS, parts, shapes)})

    def colours(v, li):
        refined = apply_calibration(rig, unflatten(v))
        return jax.vmap(lambda im, m, d: frame_samples(refined, im, m, d, pano, occlusion))(
            images, masks, li)

    cols, wts = colours(flat, log_inv)                      # (F, N, H, W, 3), (F, N, H, W)
    # Each point's samples depend on its own distance only: one directional derivative along
    # all distances at once is every point's own.
    j_d = jax.jvp(lambda li: colours(flat, li)[0], (log_inv,), (jnp.ones_like(log_inv),))[1]
    j_p = jax.lax.map(lambda e: jax.jvp(lambda v: colours(v, log_inv)[0], (flat,), (e,))[1],
                      jnp.eye(flat.shape[0], dtype=flat.dtype))     # (P, F, N, H, W, 3)

    def point_dispersion(c, w):                                     # (N, 3), (N,) -> scalar
        return view_dispersion(c[:, None, :], w[:, None])[0][0]

    c_pts = jnp.moveaxis(cols, 1, -2)                               # (F, H, W, N, 3)
    w_pts = jnp.moveaxis(wts, 1, -1)                                # (F, H, W, N)
    curv = jax.vmap(jax.vmap(jax.vmap(jax.hessian(point_dispersion))))(c_pts, w_pts)
    seen = (jnp.sum(wts, 1) >= SEEN_WEIGHT).astype(dtype)          # (F, H, W)
    # The data term is the mean over frames of each frame's mean over its compared points.
    frames = log_inv.shape[0]
    share = seen / (frames * jnp.maximum(jnp.sum(seen, (1, 2), keepdims=True), 1.0))
    jd_pts = jnp.moveaxis(j_d, 1, -2)                               # (F, H, W, N, 3)
    jp_pts = jnp.moveaxis(j_p, 2, -2)                               # (P, F, H, W, N, 3)
    c_jd = jnp.einsum("fhwiajb,fhwjb->fhwia", curv, jd_pts)
    h_dd = share * jnp.einsum("fhwia,fhwia->fhw", jd_pts, c_jd)
    h_pd = share * jnp.einsum("pfhwia,fhwia->pfhw", jp_pts, c_jd)
    h_pp = jax.lax.map(lambda a: jnp.einsum("fhw,fhwiajb,qfhwjb,fhwia->q", share, curv,
                                            jp_pts, a), jp_pts)

    # The smoothness couples only 4-neighbours (with fixed guides): one Hessian-vector
    # product per colour reads its diagonal.
    def smooth(li):
        return smoothness * refinement_loss(dict(unflatten(flat), log_inv=li), rig, images,
                                            masks, pano, 1.0, edge_scale, guides,
                                            occlusion)[1]["smooth"]

    smooth_grad = jax.grad(smooth)
    colouring = neighbour_colouring(log_inv.shape[-2:])
    for c in range(int(colouring.max()) + 1):
        pick = jnp.broadcast_to(jnp.asarray(colouring == c, dtype), log_inv.shape)
        h_dd = h_dd + pick * jax.jvp(smooth_grad, (log_inv,), (pick,))[1]
    convex = h_dd > 0
    inv_dd = jnp.where(convex, 1.0 / jnp.where(convex, h_dd, 1.0), 0.0)
    cols_pd = h_pd.reshape(h_pd.shape[0], -1)
    marginal = h_pp - (cols_pd * inv_dd.reshape(-1)) @ cols_pd.T
    data = refinement_loss(unflatten(flat), rig, images, masks, pano, smoothness, edge_scale,
                           guides, occlusion)[1]["data"]
    return {"pose": 0.5 * (h_pp + h_pp.T), "marginal": 0.5 * (marginal + marginal.T),
            "distance": h_dd, "data": data, "points": jnp.sum(seen)}


def gauge_basis(rig: Rig) -> np.ndarray:
    """(P, P - 1) orthonormal columns spanning the pose parameters the gauge leaves free:
    all but camera 1's translation along its arm from camera 0 (NumPy, concrete rig)."""
    n = rig.num_cameras
    p = 6 * (n - 1)
    arm = np.asarray(rig.translations[1], np.float64) - np.asarray(rig.translations[0],
                                                                  np.float64)
    null = np.zeros(p)
    null[3 * (n - 1): 3 * (n - 1) + 3] = arm / max(np.linalg.norm(arm), 1e-12)
    u, _, _ = np.linalg.svd(np.eye(p) - np.outer(null, null))
    return u[:, : p - 1]


@functools.partial(jax.jit, static_argnames=("pano", "smoothness", "edge_scale", "occlusion"))
def _information_jit(params, rig, images, masks, pano, smoothness, edge_scale, guides,
                     occlusion):
    return pose_information(params, rig, images, masks, pano, smoothness, edge_scale, guides,
                            occlusion)


def pose_constraint(rig: Rig, images: np.ndarray, masks: np.ndarray,
                    inv_distance: np.ndarray, config: RefineConfig = RefineConfig()) -> dict:
    """Per camera how well the frames constrain its pose at ``rig``'s calibration (NumPy
    report, an edge).

    Args:
      rig: the rig at the images' size (the refined one, typically
        :attr:`gijax.calibrate.refine.RefineResult.rig`).
      images: (F, N, h, w, 3) the frames (uint8, or float in [0, 1]); ``masks`` (F, N, h, w).
      inv_distance: (F, H, W) the frames' inverse distances on the refinement's panorama
        (:attr:`~gijax.calibrate.refine.RefineResult.inv_distance`).
      config: the refinement's settings (panorama, finest blur, smoothness, edge scale,
        occlusion margin).

    Returns ``{'cameras': [{'name', 'sigma_rotation_deg', 'sigma_translation_mm',
    'weak_direction', 'absorbed'}...], 'data', 'points'}``: per camera the predicted standard
    deviation of its rotation (degrees) and translation (millimetres) along their least
    constrained directions (``weak_direction``: the translation's, a unit vector in the rig
    frame; both deviations None where the objective does not rise along a direction that
    moves the camera: at a saddle or an unconverged point, or a pose the frames do not see at
    all), and ``absorbed``: the share of the translation's curvature along that direction
    that the re-fitted distances take away (near 1: the frames alone barely see it). Camera
    0 (the gauge) reads 0.
    """
    images = np.asarray(images)
    if images.dtype == np.uint8:
        images = images.astype(np.float32) / 255.0
    images = images.astype(np.float32)
    masks = (np.asarray(masks, np.float32) > 0.5).astype(np.float32)
    choice = choose_panorama(rig)
    pano = refine_panorama(rig, config)
    work = with_panorama_rotation(rig, choice.rotation)
    work = work.replace(rotations=jnp.asarray(work.rotations, jnp.float32),
                        translations=jnp.asarray(work.translations, jnp.float32))
    inv = np.clip(np.asarray(inv_distance, np.float64), 1.0 / MAX_DISTANCE, 1.0 / MIN_DISTANCE)
    if inv.shape != (len(images), *pano.shape):
        raise ValueError(f"inverse distances must have shape {(len(images), *pano.shape)}; "
                         f"found {inv.shape}")
    params = initial_parameters(work, jnp.asarray(np.log(inv), jnp.float32))
    fine = _prepared(images, masks, config.blur[-1], config.flatten)
    jmasks = jnp.asarray(masks)
    guides = jnp.stack([_frame_terms_jit(work, fine[f], jmasks[f], params["log_inv"][f],
                                         pano, float(config.occlusion))["colour"]
                        for f in range(len(images))])
    info = jax.device_get(_information_jit(params, work, fine, jmasks, pano,
                                           float(config.smoothness), float(config.edge_scale),
                                           guides, float(config.occlusion)))
    return constraint_report(rig, info)


def constraint_report(rig: Rig, info: dict) -> dict:
    """The per-camera report of :func:`pose_constraint` from :func:`pose_information`'s
    output (NumPy); translations and directions are in the rig frame."""
    n = rig.num_cameras
    basis = gauge_basis(rig)
    marginal = np.asarray(info["marginal"], np.float64)
    pose = np.asarray(info["pose"], np.float64)
    points = float(info["points"])
    noise = 2.0 * float(info["data"]) / max(points, 1.0)
    reduced = basis.T @ marginal @ basis
    evals, evecs = np.linalg.eigh(reduced)
    vecs = basis @ evecs                                               # (P, P - 1) columns
    bent = evals > 1e-9 * max(float(np.max(np.abs(evals))), 1e-300)
    cov = noise * (vecs[:, bent] / evals[bent]) @ vecs[:, bent].T
    flat = vecs[:, ~bent]            # directions along which the objective does not rise
    cameras = [{"name": rig.names[0], "sigma_rotation_deg": 0.0, "sigma_translation_mm": 0.0,
                "weak_direction": [0.0, 0.0, 0.0], "absorbed": 0.0}]
    for k in range(1, n):
        r = slice(3 * (k - 1), 3 * k)
        t = slice(3 * (n - 1) + 3 * (k - 1), 3 * (n - 1) + 3 * k)
        t_vals, t_vecs = np.linalg.eigh(cov[t, t])
        weak = t_vecs[:, -1]
        sigma_rot = math.degrees(math.sqrt(max(np.linalg.eigvalsh(cov[r, r])[-1], 0.0)))
        sigma_t = 1e3 * math.sqrt(max(t_vals[-1], 0.0))
        # A direction without curvature leaves the pose undetermined along it: no deviation.
        loose = [j for j in range(flat.shape[1])
                 if np.sum(flat[r, j] ** 2) + np.sum(flat[t, j] ** 2) > 0.01]
        if loose:
            sigma_rot = sigma_t = None
            part = flat[t, loose[0]]
            if np.linalg.norm(part) > 1e-6:
                weak = part / np.linalg.norm(part)
        held = float(weak @ pose[t, t] @ weak)
        kept = float(weak @ marginal[t, t] @ weak)
        cameras.append({
            "name": rig.names[k], "sigma_rotation_deg": sigma_rot, "sigma_translation_mm": sigma_t,
            "weak_direction": (weak * np.sign(weak[np.argmax(np.abs(weak))])).tolist(),
            "absorbed": float(np.clip(1.0 - kept / held, 0.0, 1.0)) if held > 0 else 1.0,
        })
    return {"cameras": cameras, "data": float(info["data"]), "points": points}


# Defaults of :func:`weak_constraint_lines`: a predicted translation deviation above 1 % of a
# camera's distance to its nearest neighbour (3 mm on the paper's 0.31 m training rig) or a
# rotation deviation above 0.1 degree.
LOOSE_SPACING_SHARE = 0.01
LOOSE_ROTATION_DEG = 0.1


def weak_constraint_lines(report: dict, rig: Rig, spacing_share: float = LOOSE_SPACING_SHARE,
                          max_rotation_deg: float = LOOSE_ROTATION_DEG) -> list:
    """One line per camera whose predicted deviation (:func:`pose_constraint`) exceeds
    ``spacing_share`` of its distance to the nearest other camera (translation) or
    ``max_rotation_deg``: the frames leave that pose loosely determined. The deviations are
    lower bounds (see the module docstring), so a camera named here is not a close call."""
    trans = np.asarray(rig.translations, np.float64)
    lines = []
    for k, cam in enumerate(report["cameras"]):
        if k == 0:
            continue
        near_mm = 1e3 * float(np.min(np.linalg.norm(np.delete(trans, k, 0) - trans[k], axis=-1)))
        mm, deg = cam["sigma_translation_mm"], cam["sigma_rotation_deg"]
        d = ", ".join(f"{x:+.2f}" for x in cam["weak_direction"])
        if mm is None:
            lines.append(f"{cam['name']}: the photometric objective does not rise along a "
                         f"direction that moves it (translation ({d}) in the rig frame): the "
                         f"frames do not see it, or the refinement did not settle; other "
                         f"frames, more steps or rounds")
        elif mm > spacing_share * near_mm or deg > max_rotation_deg:
            lines.append(
                f"{cam['name']}: the frames constrain its pose loosely (predicted deviation "
                f"{deg:.3f} deg, {mm:.2f} mm along ({d}) in the rig frame, {mm / near_mm:.1%} of "
                f"its {near_mm:.0f} mm to the nearest camera; the re-fitted distances absorb "
                f"{cam['absorbed']:.0%} of the photometric change there); frames with "
                f"structure nearer the rig, or more frames, constrain it better")
    return lines


def constraint_lines(report: dict) -> list:
    """The report as text, one line per camera after the gauge's."""
    lines = []
    for cam in report["cameras"][1:]:
        if cam["sigma_translation_mm"] is None:
            lines.append(f"  {cam['name']}: not at a minimum along a direction that moves it")
            continue
        d = ", ".join(f"{x:+.2f}" for x in cam["weak_direction"])
        lines.append(f"  {cam['name']}: {cam['sigma_rotation_deg']:.3f} deg, "
                     f"{cam['sigma_translation_mm']:.2f} mm along ({d}) (the distances absorb "
                     f"{cam['absorbed']:.0%} there)")
    return lines
