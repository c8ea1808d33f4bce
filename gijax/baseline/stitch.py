"""Stitching the reference cameras' distance maps into one panorama at the rig's reference point.

Every panorama ray leaves the reference point ``c`` in direction ``u``. For one reference
camera with inverse-distance map ``rho`` (along its own rays, from its own centre), the
panorama ray meets that camera's surface where the point ``p(s) = c + u / s`` (``s`` = inverse
distance from ``c``) satisfies ``1 / |p(s) - t_r| = rho(project(p(s)))``. The map is resampled
backwards: ``s`` is marched from near to far over a fixed list of inverse distances, all
reference cameras at once, and a camera's crossing from "in front of its surface" to "behind
it" (with its map continuous across the step) is refined linearly.

When ``c`` is not the camera's centre, the near part of the panorama ray runs across the
camera's view and meets many of its pixels; a camera's own near outliers (a patch of wrong
matches) then produce crossings that look like surfaces. A crossing is therefore accepted only
if more of the other cameras agree with it (their map at the point's projection is within a
tolerance of the point's distance from them) than look through it (their map is farther at
both neighbouring steps: the point is free space). The first accepted crossing is the
camera's estimate.

The estimates are blended robustly in inverse distance: the cluster of mutually agreeing
estimates with the largest summed confidence is averaged with those confidences (the pair's
pixel displacement times ``|dq/ds| = q^2 cos / s^2``, how fast the camera's inverse distance
``q`` follows the panorama's along the ray). Small holes are filled from their neighbours;
panorama pixels that no two cameras can see at any candidate distance are invalid and stay so.
"""

from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp

from gijax.baseline.camera_select import camera_at
from gijax.baseline.views import MatchView, sample_mask_nearest, view_pixels
from gijax.geometry import cameras as cam_lib
from gijax.geometry.panorama import Panorama
from gijax.geometry.panorama_frame import panorama_rays
from gijax.geometry.rig import Rig, map_cameras, rig_to_camera
from gijax.numerics import safe_denominator, safe_norm
from gijax.sampling import bilinear_sample

Array = jax.Array
# Metres: a marched point this close to a camera centre is treated as this far from it.
_MIN_RANGE = 1e-9


def pair_visibility(rig: Rig, masks: Array, candidates: Array, pano: Panorama) -> Array:
    """(H, W) bool: at some candidate distance from the reference point, >= 2 cameras see the point.

    ``masks`` (N, h, w) are the cameras' raw-image masks (1 = valid).
    """
    dirs = panorama_rays(rig, pano, candidates.dtype)
    pts = rig.reference + candidates[:, None, None, None] * dirs[None]

    def one(cam, rot, trans, _, mask):
        px, ok = cam_lib.project(cam, (pts - trans) @ rot)
        return sample_mask_nearest(mask, px, ok)

    seen = map_cameras(one, rig, masks)  # (N, D, H, W)
    return jnp.any(jnp.sum(seen.astype(jnp.int32), 0) >= 2, axis=0)


def _probe_camera(rig: Rig, view: MatchView, ref, packed: Array, dirs: Array, s) -> tuple:
    """Camera ``ref``'s view of the panorama points ``c + dirs / s`` (Hp, Wp, 3).

    Returns ``f = q - rho`` (q: inverse distance of the point from the camera, rho: the map
    at its projection), whether the map was sampled there, the sampled weight, ``q`` and the
    cosine between the panorama ray and the camera ray through the point; each (Hp, Wp).
    """
    pc = rig_to_camera(rig, ref, rig.reference + dirs / s)
    px, ok = view_pixels(view, camera_at(rig, ref), pc)
    vals, ok = bilinear_sample(packed, px, ok)
    den = vals[..., 1]
    # Bilinear samples that lean on invalid map pixels are not trusted.
    good = ok & (den > 0.5)
    safe = jnp.where(good, den, 1.0)
    rho = vals[..., 0] / safe
    dist = jnp.maximum(safe_norm(pc), _MIN_RANGE)
    q = 1.0 / dist
    # The camera ray through the point, in the rig frame, against the panorama ray.
    cos = jnp.sum((pc @ rig.rotations[ref].T) * dirs, -1) / dist
    return q - rho, good, vals[..., 2] / safe, q, cos


def resample_to_panorama(rig: Rig, view: MatchView, refs: Sequence[int], inv_maps, valid_maps,
                         weight_maps, pano: Panorama, inverse_samples: Array,
                         consistency_tol: float, consistency_rel: float = 0.1,
                         jump_slack: float = 2.0, jump_rel: float = 0.1) -> dict:
    """Every reference camera's map re-expressed along the panorama rays, checked against the others.

    Args:
      refs: reference camera indices; ``inv_maps[i]`` (1/m, along camera ``refs[i]``'s rays
        from its centre), ``valid_maps[i]`` and ``weight_maps[i]`` (pixels of displacement)
        are its maps, either stacked (R, H, W) (cameras of one model and size) or sequences.
      inverse_samples: (S,) decreasing inverse distances from the reference point (near to
        far) at which every ray is marched.
      consistency_tol, consistency_rel: a crossing of camera r at a point with inverse
        distance ``q_j`` from camera j agrees with j when ``|q_j - rho_j| <= consistency_tol
        + consistency_rel * q_j`` (1/m) and is contradicted by j when j sees farther than
        that at both neighbouring march steps (j looks through the point).
      jump_slack, jump_rel: a sign change only counts when the map changes by at most
        ``jump_slack * |dq| + jump_rel * rho`` between the two steps (``q`` = inverse distance
        from the camera to the marched point): a jump of the map (outlier, occlusion edge) is
        not a surface.

    Returns dict of (R, Hp, Wp) arrays: ``inv_distance`` (1/m from the reference point, 0 where
    not found), ``weight`` (confidence, 0 where not found) and ``valid``.
    """
    dirs = panorama_rays(rig, pano, inverse_samples.dtype)
    stacked = isinstance(inv_maps, jax.Array) and inv_maps.ndim == 3

    def pack(inv, val, w):
        v = val.astype(inv.dtype)
        return jnp.stack([inv * v, v, w * v], -1)

    if stacked:
        packed = jax.vmap(pack)(inv_maps, valid_maps, weight_maps)
        ref_idx = jnp.asarray(refs, jnp.int32)

        def probe(s):
            return jax.vmap(lambda r, p: _probe_camera(rig, view, r, p, dirs, s))(ref_idx, packed)
    else:
        packed = [pack(i, v, w) for i, v, w in zip(inv_maps, valid_maps, weight_maps)]

        def probe(s):
            outs = [_probe_camera(rig, view, r, p, dirs, s) for r, p in zip(refs, packed)]
            return tuple(jnp.stack(x) for x in zip(*outs))

    n = len(refs)
    others = ~jnp.eye(n, dtype=bool)[:, :, None, None]  # (R, R, 1, 1): j != r

    def step(carry, s_pair):
        found, s_hit, w_hit, f0, g0, q0 = carry
        s_prev, s_next = s_pair
        f1, g1, w1, q1, cos1 = probe(s_next)
        # A sign change caused by a jump of the map (an outlier or an occlusion edge seen by
        # this camera) rather than by the ray passing through the surface is not a hit.
        d_rho = jnp.abs((q1 - f1) - (q0 - f0))
        smooth = d_rho <= jump_slack * jnp.abs(q1 - q0) + jump_rel * (q1 - f1)
        cross = g0 & g1 & (f0 > 0) & (f1 <= 0) & smooth
        t = f0 / jnp.where(cross, f0 - f1, 1.0)  # (R, Hp, Wp), fraction of the step
        # Every other camera's f at camera r's crossing point, interpolated linearly (R, R, ..):
        # a single camera's map is locally consistent with an outlier patch of its own, but
        # the other cameras see through such a point (free space) or confirm a real surface.
        fj = f0[None] + t[:, None] * (f1 - f0)[None]
        tol = consistency_tol + consistency_rel * (q0 + t * (q1 - q0))[None]
        seen = (g0 & g1)[None] & others
        agree = seen & ((jnp.abs(fj) <= tol) | ((f0 > 0) & (f1 <= 0))[None])
        through = seen & (jnp.minimum(f0, f1)[None] > tol)
        n_agree = jnp.sum(agree, 1)
        n_through = jnp.sum(through, 1)
        accept = cross & ~found & (n_agree > n_through)
        s_hit = jnp.where(accept, s_prev + t * (s_next - s_prev), s_hit)
        # Confidence ~ 1 / (std of the panorama inverse distance): the map's resolution
        # (displacement of the pair) times |d q / d s| = q^2 cos / s^2, which is small where
        # the panorama ray runs across the camera's view (far from the reference point).
        conf = w1 * jnp.maximum(cos1, 0.0) * (q1 / s_next) ** 2
        w_hit = jnp.where(accept, conf, w_hit)
        return (found | accept, s_hit, w_hit, f1, g1, q1), None

    f0, g0, _, q0, _ = probe(inverse_samples[0])
    zeros = jnp.zeros(f0.shape, f0.dtype)
    init = (jnp.zeros(f0.shape, bool), zeros, zeros, f0, g0, q0)
    pairs = (inverse_samples[:-1], inverse_samples[1:])
    (found, s_hit, w_hit, _, _, _), _ = jax.lax.scan(step, init, pairs)
    return dict(inv_distance=s_hit, weight=jnp.where(found, w_hit, 0.0), valid=found)


def fill_holes(inv: Array, valid: Array, allowed: Array, iterations: int) -> tuple[Array, Array]:
    """Fill invalid pixels inside ``allowed`` with the mean of their valid 3x3 neighbours.

    Repeated ``iterations`` times (so holes up to about ``2 * iterations`` pixels wide close);
    columns wrap around (longitude), rows do not.
    """
    for _ in range(iterations):
        v = valid.astype(inv.dtype)
        both = jnp.stack([inv * v, v], -1)
        # Wrap one column each side (longitude), zero-pad rows, then a 3x3 box sum.
        both = jnp.concatenate([both[:, -1:], both, both[:, :1]], axis=1)
        both = jnp.pad(both, ((1, 1), (0, 0), (0, 0)))
        sums = jax.lax.reduce_window(both, 0.0, jax.lax.add, (3, 3, 1), (1, 1, 1), "VALID")
        num, den = sums[..., 0], sums[..., 1]
        fill = ~valid & allowed & (den > 0)
        inv = jnp.where(fill, num / jnp.maximum(den, 1.0), inv)
        valid = valid | fill
    return inv, valid


def blend_estimates(inv: Array, valid: Array, weight: Array, tol, rel: float = 0.1) -> Array:
    """Robust blend (Hp, Wp) of the reference cameras' estimates (R, Hp, Wp) in 1/m.

    The estimate with the largest summed weight of estimates within ``tol + rel * inv`` of it
    picks the cluster; that cluster's members are averaged in inverse distance with their
    weights. One camera's outlier cannot drag the others' agreeing estimates (a plain weighted
    mean would: a near outlier has a large inverse distance). 0 where no estimate is valid.
    """
    w = jnp.where(valid, jnp.maximum(weight, 1e-3), 0.0)
    close = jnp.abs(inv[:, None] - inv[None]) <= tol + rel * inv[:, None]  # (R, R, Hp, Wp)
    support = jnp.sum(close * w[None], 1)
    best = jnp.argmax(jnp.where(valid, support, -1.0), 0)
    member = jnp.take_along_axis(close, best[None, None], 0)[0] & valid
    wm = w * member
    return jnp.sum(wm * inv, 0) / safe_denominator(jnp.sum(wm, 0))


def stitch(rig: Rig, view: MatchView, refs: Sequence[int], inv_maps, valid_maps, weight_maps,
           masks: Array, candidates: Array, pano: Panorama, samples: int = 96,
           fill_iterations: int = 2) -> dict:
    """Blend the reference cameras' maps into the panorama.

    Args:
      refs: reference camera indices; ``inv_maps[i]`` etc. are camera ``refs[i]``'s maps (1/m).
        The maps are either sequences of (H_i, W_i) arrays (looped over) or stacked
        (R, H, W) arrays (mapped over with one compiled body; all cameras must then share
        model and size).
      masks: (N, h, w) raw-image masks of all cameras (for the pair-visibility test).
      candidates: (D,) metres; the march covers 0.5 * d_min .. 2 * d_max from the reference.
      samples: number of march steps (uniform in inverse distance).

    Cameras agree within half the mean candidate step in inverse distance plus 10 %.

    Returns dict(inv_distance (Hp, Wp) 1/m, NaN where invalid; valid (Hp, Wp) bool;
    visible (Hp, Wp) bool, the pair-visibility mask).
    """
    dtype = candidates.dtype
    s_near = 2.0 / candidates[0]
    s_far = 0.5 / candidates[-1]
    inverse_samples = jnp.linspace(s_near, s_far, samples).astype(dtype)
    # Agreement between cameras within about half a candidate step (in inverse distance).
    tol = 0.5 * (1.0 / candidates[0] - 1.0 / candidates[-1]) / (candidates.shape[0] - 1)
    est = resample_to_panorama(rig, view, refs, inv_maps, valid_maps, weight_maps, pano,
                               inverse_samples, tol)
    inv = blend_estimates(est["inv_distance"], est["valid"], est["weight"], tol)
    visible = pair_visibility(rig, masks, candidates, pano)
    have = jnp.any(est["valid"], 0) & visible
    inv, have = fill_holes(inv, have, visible, fill_iterations)
    return dict(inv_distance=jnp.where(have, inv, jnp.nan), valid=have, visible=visible)
