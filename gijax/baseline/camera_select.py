"""Per reference pixel, the other camera to match against, and the sweep coordinates into it.

For a reference camera ``r`` and each pixel of its matching view, the point at distance ``d``
along the pixel's ray from the camera centre is ``t_r + R_r (d * ray)`` in the rig frame. The
chosen partner camera is the one whose matching-view projections of the points at the nearest
and the farthest candidates are furthest apart (the largest displacement, i.e. the best
distance resolution), among cameras that see both points (lens and mask) with a displacement
above ``min_displacement`` pixels. Everything here depends only on the rig, the candidate
list and the masks, so it can be computed once per rig.
"""

from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp

from gijax.baseline.views import MatchView, sample_mask_nearest, view_pixels, view_rays
from gijax.geometry.rig import Rig, is_homogeneous, rig_to_camera
from gijax.numerics import safe_norm

Array = jax.Array


def camera_at(rig: Rig, i):
    """Camera ``i`` of the rig; ``i`` may be a traced index when all cameras share model and size."""
    if isinstance(i, int):
        return rig.cameras[i]
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x)[i], *rig.cameras)


def item_at(items: Sequence[Array], i):
    """``items[i]`` for a Python or a traced index (traced: all items must share one shape)."""
    return items[i] if isinstance(i, int) else jnp.stack(list(items))[i]


def reference_rays(rig: Rig, view: MatchView, ref, view_mask: Array) -> tuple[Array, Array]:
    """Rig-frame unit rays (H, W, 3) of camera ``ref``'s matching view and their validity."""
    rays, ok = view_rays(view, camera_at(rig, ref))
    return rays @ rig.rotations[ref].T, ok & (view_mask > 0.5)


def points_at(rig: Rig, ref, rays_rig: Array, distances: Array) -> Array:
    """Rig-frame points (D, H, W, 3) at ``distances`` (D,) metres along rays from camera ``ref``."""
    return rig.translations[ref] + distances[:, None, None, None] * rays_rig[None]


def project_into_view(rig: Rig, view: MatchView, j, view_mask: Array,
                      points: Array) -> tuple[Array, Array]:
    """Rig-frame points (..., 3) to camera ``j``'s matching-view pixels (..., 2) and validity.

    Validity includes the lens, the matching image bounds and camera ``j``'s view mask.
    """
    px, ok = view_pixels(view, camera_at(rig, j), rig_to_camera(rig, j, points))
    return px, sample_mask_nearest(view_mask, px, ok)


def for_each_camera(rig: Rig, view_masks: Sequence[Array], body, init):
    """``carry = body(j, carry)`` for every camera ``j``.

    When all cameras share model and size (and so do their view masks) this is one
    ``fori_loop`` with a traced ``j`` (one compiled body, memory independent of the camera
    count); otherwise a Python loop with integer ``j``.
    """
    shapes = {m.shape for m in view_masks}
    if is_homogeneous(rig) and len(shapes) == 1:
        return jax.lax.fori_loop(0, rig.num_cameras, body, init)
    for j in range(rig.num_cameras):
        init = body(j, init)
    return init


def select_best_camera(rig: Rig, view: MatchView, ref, candidates: Array,
                       view_masks: Sequence[Array], min_displacement: float = 1.0) -> dict:
    """The partner camera of every pixel of reference camera ``ref``'s matching view.

    Args:
      candidates: (D,) ascending distances, metres; only the first and last are used.
      view_masks: per camera its (H_j, W_j) matching-view mask (1 = valid).
      min_displacement: pixels; a partner must move the point by more than this.

    Returns dict with ``best`` (H, W) int32 camera index (``ref`` where none qualifies),
    ``displacement`` (H, W) pixels in the partner's view (0 where none) and ``valid`` (H, W).
    ``ref`` is a camera index (a traced index works when all cameras share model and size).
    Ties go to the lower camera index.
    """
    rays, ref_ok = reference_rays(rig, view, ref, item_at(view_masks, ref))
    ends = jnp.stack([candidates[0], candidates[-1]])
    pts = points_at(rig, ref, rays, ends)

    def body(j, carry):
        best, best_disp = carry
        px, ok = project_into_view(rig, view, j, item_at(view_masks, j), pts)
        disp = safe_norm(px[0] - px[1])
        usable = ok[0] & ok[1] & (disp > min_displacement) & ref_ok & (j != ref)
        # Only a strictly larger displacement replaces: ties keep the lower index.
        better = usable & (disp > best_disp)
        return jnp.where(better, j, best), jnp.where(better, disp, best_disp)

    init = (jnp.full(rays.shape[:2], ref, jnp.int32), jnp.zeros(rays.shape[:2], rays.dtype))
    best, best_disp = for_each_camera(rig, view_masks, body, init)
    valid = best != ref
    return dict(best=best, displacement=jnp.where(valid, best_disp, 0.0), valid=valid)


def sweep_coords(rig: Rig, view: MatchView, ref, candidates: Array, best: Array,
                 view_masks: Sequence[Array]) -> tuple[Array, Array]:
    """Partner-view pixels (D, H, W, 2) of every candidate point, and their validity (D, H, W).

    Only the partner camera ``best`` (H, W) of each pixel is kept, so memory does not grow
    with the number of cameras. Pixels without a partner (``best == ref``) are invalid.
    """
    rays, ref_ok = reference_rays(rig, view, ref, item_at(view_masks, ref))
    pts = points_at(rig, ref, rays, candidates)

    def body(j, carry):
        coords, valid = carry
        px, ok = project_into_view(rig, view, j, item_at(view_masks, j), pts)
        pick = ((best == j) & (j != ref))[None]
        return jnp.where(pick[..., None], px, coords), jnp.where(pick, ok, valid)

    init = (jnp.zeros(pts.shape[:-1] + (2,), pts.dtype), jnp.zeros(pts.shape[:-1], bool))
    coords, valid = for_each_camera(rig, view_masks, body, init)
    return coords, valid & ref_ok[None]
