"""Stitching the reference cameras' distance maps into one panorama at the rig's reference point.

Every panorama ray leaves the reference point ``c`` in direction ``u``. For one reference
camera with inverse-distance map ``rho`` (along its own rays, from its own centre), the
panorama ray meets that camera's surface where the point ``p(s) = c + u / s`` (``s`` = inverse
distance from ``c``) satisfies ``1 / |p(s) - t_r| = rho(project(p(s)))``. The map is resampled
backwards: ``s`` is marched from near to far over a fixed list of inverse distances and the
first sign change of ``1 / |p - t_r| - rho`` (the nearest surface along the ray) is refined
linearly. Backward resampling leaves no splatting holes when the panorama is finer than the
matching views.

The reference cameras' estimates are blended in inverse distance, weighted by the pixel
displacement of the camera pair that produced them (a larger displacement resolves distance
better). Small holes are filled from their neighbours; panorama pixels that no two cameras can
see at any candidate distance are invalid and stay so.
"""

from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp

from gijax.baseline.camera_select import camera_at
from gijax.baseline.views import MatchView, sample_mask_nearest, view_pixels
from gijax.geometry import cameras as cam_lib
from gijax.geometry.panorama import Panorama, ray_grid
from gijax.geometry.rig import Rig, map_cameras, rig_to_camera
from gijax.sampling import bilinear_sample

Array = jax.Array


def pair_visibility(rig: Rig, masks: Array, candidates: Array, pano: Panorama) -> Array:
    """(H, W) bool: at some candidate distance from the reference point, >= 2 cameras see the point.

    ``masks`` (N, h, w) are the cameras' raw-image masks (1 = valid).
    """
    dirs = ray_grid(pano, candidates.dtype)
    pts = rig.reference + candidates[:, None, None, None] * dirs[None]

    def one(cam, rot, trans, _, mask):
        px, ok = cam_lib.project(cam, (pts - trans) @ rot)
        return sample_mask_nearest(mask, px, ok)

    seen = map_cameras(one, rig, masks)  # (N, D, H, W)
    return jnp.any(jnp.sum(seen.astype(jnp.int32), 0) >= 2, axis=0)


def resample_to_panorama(rig: Rig, view: MatchView, ref, inv_map: Array, valid: Array,
                         weight: Array, pano: Panorama, inverse_samples: Array,
                         jump_slack: float = 2.0, jump_rel: float = 0.1) -> dict:
    """One reference camera's map (H, W) in 1/m along its rays -> panorama estimate (Hp, Wp).

    ``inverse_samples`` (S,) are decreasing inverse distances from the reference point (near to
    far) at which the ray is marched. A sign change only counts when the map changes by at
    most ``jump_slack * |dq| + jump_rel * rho`` between the two steps (``q`` = inverse distance
    from the camera to the marched point), which rejects outliers and occlusion edges. Returns dict(inv_distance, weight, valid), each (Hp, Wp).
    """
    dirs = ray_grid(pano, inv_map.dtype)
    packed = jnp.stack([inv_map * valid, valid.astype(inv_map.dtype), weight * valid], -1)

    def probe(s):
        pc = rig_to_camera(rig, ref, rig.reference + dirs / s)
        px, ok = view_pixels(view, camera_at(rig, ref), pc)
        vals, ok = bilinear_sample(packed, px, ok)
        den = vals[..., 1]
        good = ok & (den > 0.5)
        rho = vals[..., 0] / jnp.where(good, den, 1.0)
        q = 1.0 / jnp.maximum(jnp.linalg.norm(pc, axis=-1), 1e-9)
        return q - rho, good, vals[..., 2] / jnp.where(good, den, 1.0), q

    f0, g0, _, q0 = probe(inverse_samples[0])
    zeros = jnp.zeros(dirs.shape[:2], inv_map.dtype)

    def step(carry, s_pair):
        found, s_hit, w_hit, f_prev, g_prev, q_prev = carry
        s_prev, s_next = s_pair
        f, g, w, q = probe(s_next)
        # A sign change caused by a jump of the map (an outlier or an occlusion edge seen by
        # this camera) rather than by the ray passing through the surface is not a hit: the
        # map may change by at most its own slope budget between two steps.
        d_rho = jnp.abs((q - f) - (q_prev - f_prev))
        smooth = d_rho <= jump_slack * jnp.abs(q - q_prev) + jump_rel * (q - f)
        cross = g_prev & g & (f_prev > 0) & (f <= 0) & smooth & ~found
        t = f_prev / jnp.where(cross, f_prev - f, 1.0)
        s_hit = jnp.where(cross, s_prev + t * (s_next - s_prev), s_hit)
        w_hit = jnp.where(cross, w, w_hit)
        return (found | cross, s_hit, w_hit, f, g, q), None

    init = (jnp.zeros(dirs.shape[:2], bool), zeros, zeros, f0, g0, q0)
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

    Returns dict(inv_distance (Hp, Wp) 1/m, NaN where invalid; valid (Hp, Wp) bool;
    visible (Hp, Wp) bool, the pair-visibility mask).
    """
    dtype = candidates.dtype
    s_near = 2.0 / candidates[0]
    s_far = 0.5 / candidates[-1]
    inverse_samples = jnp.linspace(s_near, s_far, samples).astype(dtype)
    if isinstance(inv_maps, jax.Array) and inv_maps.ndim == 3:
        def one(args):
            r, inv_r, val_r, w_r = args
            return resample_to_panorama(rig, view, r, inv_r, val_r, w_r, pano, inverse_samples)

        est = jax.lax.map(one, (jnp.asarray(refs, jnp.int32), inv_maps, valid_maps, weight_maps))
    else:
        ests = [resample_to_panorama(rig, view, r, i, v, w, pano, inverse_samples)
                for r, i, v, w in zip(refs, inv_maps, valid_maps, weight_maps)]
        est = {k: jnp.stack([e[k] for e in ests]) for k in ests[0]}
    w = jnp.where(est["valid"], jnp.maximum(est["weight"], 1e-3), 0.0)
    den = jnp.sum(w, 0)
    inv = jnp.sum(w * est["inv_distance"], 0) / jnp.maximum(den, 1e-12)
    visible = pair_visibility(rig, masks, candidates, pano)
    have = jnp.any(est["valid"], 0) & visible
    inv, have = fill_holes(inv, have, visible, fill_iterations)
    return dict(inv_distance=jnp.where(have, inv, jnp.nan), valid=have, visible=visible)
