r"""A differentiable figure of merit for a rig layout: predicted inverse-distance error.

Definition
----------
For the layout's rig (reference point ``o`` = centroid of the camera centres ``t_c``) and each
ray ``r`` of a small hemisphere grid (solid angle ``omega_r``):

* **Soft visibility** ``v_rc`` in (0, 1): camera ``c`` sees the swept points ``o + d r`` at
  ``samples`` distances ``d`` spread geometrically over ``[d_min, d_max]``. Per point it is the
  product of ``sigmoid(margin_fov / tau_a)`` (the angular margin between the viewing direction in
  the camera frame and the field-of-view edge, ``tau_a = fov_softness_deg``) and
  ``sigmoid(margin_occ / tau_d)`` (how far, in the mounting plane, the viewing segment passes
  outside the occluder cylinder while it is within the cylinder's height,
  ``tau_d = occluder_softness``); over the samples the factors multiply. As the widths go to 0
  this is the 0/1 validity that the rig's masks and projection give.
  A clearance factor ``sigmoid((closest - d_min / 2) / tau_d)`` (the swept segment keeps away
  from the lens, as in the rig-aware candidate solver) multiplies it.
* **Matched** ``m_r``: the probability that at least two cameras see the ray when camera ``c``
  does so with probability ``v_rc`` independently,
  ``1 - prod_c (1 - v_c) - sum_c v_c prod_{c' != c} (1 - v_c')``; exactly 0/1 for 0/1 inputs.
* **Candidates**: the rig-aware GI list ``d_0 < ... < d_{n-1}``
  (:func:`gijax.candidates.rig_aware.solve_equal_steps`) of the terms
  ``p = (o - t_c).r``, ``q = |(o - t_c) x r|``, pixel scales ``s_rc`` (the projection's pixels
  per radian at the feature, along its motion) and the soft weights ``omega_r m_r v_rc``.
  The list moves with the layout (implicit-function derivative).
* **Step resolution**: step ``i`` (from ``d_i`` to ``d_{i+1}``) changes inverse distance by
  ``du_i = 1/d_i - 1/d_{i+1}`` and moves the feature in camera ``c`` by
  ``s_rc (phi_rc(d_i) - phi_rc(d_{i+1}))`` pixels (``phi = atan2(q, d + p)``, the parallax
  angle; the same per-step displacement the candidate solver equalises). Independent 1-pixel
  matching errors in the cameras that see the ray combine to an inverse-distance error

  .. math:: e_{ri} = \sigma\, \Delta u_i \Big/ \sqrt{\textstyle\sum_c v_{rc}\,
            (s_{rc}\,\Delta\varphi_{rci})^2 + \epsilon^2}

  (``sigma = pixel_error``), so every extra unoccluded camera that sees the ray lowers it. The
  ray's resolution ``e_r`` is the mean over the ``n - 1`` steps, in 1/m.
* **Expected error**: a ray that no two cameras see can only be guessed; a guess at the middle
  of the inverse-distance range errs by ``g = (1/d_min - 1/d_max) / 4`` on average (uniform
  inverse distances). The ray's error is ``m_r min~(e_r, g) + (1 - m_r) g`` with the smooth
  minimum ``e g / (e + g)``, and the objective is its solid-angle mean

  .. math:: J = \sum_r \omega_r\,[m_r\,\tilde e_r + (1 - m_r)\, g] \Big/ \sum_r \omega_r
            \;-\; w_{cov}\, C, \qquad C = \sum_r \omega_r m_r \Big/ \sum_r \omega_r

  in 1/m: lower is better. ``C`` is the (soft) coverage, the solid-angle fraction of the
  hemisphere seen by at least two cameras; ``w_cov = coverage_weight`` (default 0) rewards it
  beyond what the expected error already does.

Everything is smooth in the camera positions, heights and orientations (the occluder margin is
piecewise smooth: where the closest point of the segment switches between its end and interior
the margin is continuous with a kinked derivative). The hard (0/1) coverage for reporting uses
the same margins with a step instead of the sigmoid.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp

from gijax.candidates import parallax as par
from gijax.candidates.rig_aware import RigTerms, parallax_angles, solve_equal_steps
from gijax.design.spec import DesignSpec, Layout
from gijax.geometry.layouts import synthetic_camera
from gijax.geometry.rotations import axis_angle_to_matrix
from gijax.numerics import safe_denominator, safe_div, safe_norm, unit

Array = jax.Array
_EPS_PX = 1e-3  # pixels: keeps the step resolution finite where no camera moves the feature
_FAR_MARGIN = 1.0  # metres: occluder margin of a segment that never reaches the cylinder's height
_FLAT = 1e-9  # |w_z| below which a segment counts as horizontal (never crosses a cap plane)


def free_layout(layout: Layout, spec: DesignSpec) -> Layout:
    """The layout with the parts the spec holds fixed set to zero (zero gradient there too)."""
    h = layout.heights if spec.heights else jnp.zeros_like(layout.heights)
    w = layout.rotvecs if spec.orientations else jnp.zeros_like(layout.rotvecs)
    return layout.replace(heights=h, rotvecs=w)


def layout_pose(layout: Layout, spec: DesignSpec):
    """Rotations (N, 3, 3), camera centres (N, 3) and the reference point (3,) of a layout."""
    lay = free_layout(layout, spec)
    rot = axis_angle_to_matrix(lay.rotvecs)
    trans = jnp.concatenate([lay.positions, lay.heights[:, None]], axis=-1)
    return rot, trans, jnp.mean(trans, axis=0)


def design_camera(spec: DesignSpec, dtype):
    """The spec's equidistant camera with its intrinsics in ``dtype``."""
    cam = synthetic_camera(spec.camera_size, spec.focal, spec.fov_deg)
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), cam)


def occluder_margin(spec: DesignSpec, origin: Array, target: Array) -> Array:
    """Signed distance (m) by which the segment ``origin -> target`` misses the occluder.

    The cylinder stands on the rig origin, radius ``occluder_radius``, z in
    ``[0, occluder_height]``. The margin is the smallest horizontal distance from the cylinder's
    axis of the part of the segment inside that height range, minus the radius: negative when the
    segment passes through the cylinder (including its caps), ``_FAR_MARGIN`` when the segment
    never enters the height range. Broadcasts over leading shapes of (..., 3) inputs.
    """
    z0, z1 = 0.0, spec.occluder_height
    v = target - origin
    length = safe_norm(v)
    w = unit(v)
    h, wz = origin[..., 2], w[..., 2]
    up, down = wz > _FLAT, wz < -_FLAT
    wz_safe = jnp.where(up | down, wz, 1.0)
    inside = (h >= z0) & (h <= z1)
    t_a, t_b = (z0 - h) / wz_safe, (z1 - h) / wz_safe
    t_in = jnp.where(up, t_a, jnp.where(down, t_b, jnp.where(inside, 0.0, length)))
    t_out = jnp.where(up, t_b, jnp.where(down, t_a, jnp.where(inside, length, -1.0)))
    lo = jnp.clip(t_in, 0.0, length)
    hi = jnp.clip(t_out, 0.0, length)
    reaches = (t_out > jnp.maximum(t_in, 0.0)) & (t_in < length)
    oxy, wxy = origin[..., :2], w[..., :2]
    t_star = safe_div(-jnp.sum(oxy * wxy, axis=-1), jnp.sum(wxy * wxy, axis=-1))
    t_star = jnp.clip(t_star, lo, jnp.maximum(hi, lo))
    closest = safe_norm(oxy + t_star[..., None] * wxy)
    return jnp.where(reaches, closest - spec.occluder_radius, _FAR_MARGIN)


# One compiled program per spec: the margins are most of the objective's work, and eager
# callers (plots, reports) would otherwise dispatch their hundreds of operations one by one.
@functools.partial(jax.jit, static_argnames=("spec",))
def _margins(layout: Layout, spec: DesignSpec):
    """Field-of-view margins (C, S, R) radians, occluder margins (C, S, R) metres, lens
    clearance margins (C, R) metres, and the parallax terms p, q (C, R), pixel scales (C, R),
    solid angles (R,)."""
    rot, trans, ref = layout_pose(layout, spec)
    dt = trans.dtype
    rays, solid = par.rays_and_solid_angles(spec.pano, dt)
    ds = par.sample_distances(spec.d_min, spec.d_max, spec.samples, dt)  # (S,)
    pts = ref + ds[:, None, None] * rays[None]  # (S, R, 3)

    view = pts[None] - trans[:, None, None, :]  # (C, S, R, 3) rig frame
    view_cam = jnp.einsum("csrk,ckj->csrj", view, rot)  # R_c^T v
    off_axis = jnp.arctan2(safe_norm(view_cam[..., :2]), view_cam[..., 2])
    fov_margin = 0.5 * math.radians(spec.fov_deg) - off_axis
    occ_margin = occluder_margin(spec, trans[:, None, None, :], pts[None])

    # The same parallax terms, lens clearance and pixel scales as the rig-aware solver.
    a, p, q = par.parallax_offsets(ref, trans, rays)  # (C, 3), (C, R)
    clear_margin = par.closest_approach(p, q, spec.d_min, spec.d_max) - 0.5 * spec.d_min
    cam = design_camera(spec, dt)
    move = par.motion_directions(a, p, q, rays)  # (C, R, 3)
    scale = jax.vmap(lambda r_c, e: par.pixels_per_radian(cam, r_c, rays, e))(rot, move)
    return fov_margin, occ_margin, clear_margin, p, q, scale, solid


def _visibility(fov_margin, occ_margin, clear_margin, spec: DesignSpec, hard: bool):
    if hard:
        per_point = (fov_margin >= 0.0) & (occ_margin >= 0.0)
        return (jnp.all(per_point, axis=1) & (clear_margin >= 0.0)).astype(fov_margin.dtype)
    sig_a = jax.nn.sigmoid(fov_margin / math.radians(spec.fov_softness_deg))
    sig_d = jax.nn.sigmoid(occ_margin / spec.occluder_softness)
    sig_c = jax.nn.sigmoid(clear_margin / spec.occluder_softness)
    return jnp.prod(sig_a * sig_d, axis=1) * sig_c  # (C, R)


def at_least_two(v: Array) -> Array:
    """P(at least two of the cameras see the ray) for independent probabilities v (C, R)."""
    miss = 1.0 - v
    none = jnp.prod(miss, axis=0)
    # prod over c' != c of (1 - v_c'), without dividing by (1 - v_c) (which may be 0).
    eye = jnp.eye(v.shape[0], dtype=bool)[:, :, None]
    others = jnp.prod(jnp.where(eye, 1.0, miss[None]), axis=1)  # (C, R)
    one = jnp.sum(v * others, axis=0)
    return jnp.clip(1.0 - none - one, 0.0, 1.0)


def objective_terms(layout: Layout, spec: DesignSpec) -> dict:
    """The objective and its parts for one layout (pure; jit/grad/vmap-able).

    Returns a dict of scalars: ``objective`` J (1/m, lower is better, without the constraint
    penalty), ``expected_error`` (1/m, J without the coverage reward), ``resolution`` (1/m, the
    mean step resolution over matched rays, weighted by ``omega_r m_r``), ``coverage`` (soft
    coverage fraction), ``hard_coverage`` (0/1 visibility; no gradient), ``mean_step_px``
    (mean displacement of a GI step over ray/camera pairs, pixels), ``guess_error`` (g), and
    ``candidates`` (n,) metres.
    """
    fov_m, occ_m, clr_m, p, q, scale, solid = _margins(layout, spec)
    v = _visibility(fov_m, occ_m, clr_m, spec, hard=False)  # (C, R)
    m = at_least_two(v)  # (R,)
    weight = solid[None] * m[None] * v
    terms = RigTerms(along=p.reshape(-1), perp=q.reshape(-1), weight=weight.reshape(-1),
                     scale=scale.reshape(-1))
    d = solve_equal_steps(terms, spec.num_candidates, spec.d_min, spec.d_max)
    u = 1.0 / d
    du = u[:-1] - u[1:]  # (n-1,) > 0
    phi = parallax_angles(terms, u).reshape((-1,) + q.shape)  # (n, C, R)
    step_px = scale[None] * (phi[:-1] - phi[1:])  # (n-1, C, R)
    power = jnp.sum(v[None] * step_px ** 2, axis=1)  # (n-1, R)
    res = spec.pixel_error * du[:, None] / jnp.sqrt(power + _EPS_PX ** 2)
    ray_res = jnp.mean(res, axis=0)  # (R,)
    guess = 0.25 * (1.0 / spec.d_min - 1.0 / spec.d_max)
    capped = ray_res * guess / (ray_res + guess)
    total = jnp.sum(solid)
    expected = jnp.sum(solid * (m * capped + (1.0 - m) * guess)) / total
    coverage = jnp.sum(solid * m) / total
    hard_v = _visibility(fov_m, occ_m, clr_m, spec, hard=True)
    hard_cov = jnp.sum(solid * (jnp.sum(hard_v, axis=0) >= 2)) / total
    wsum = safe_denominator(jnp.sum(weight))
    return {
        "objective": expected - spec.coverage_weight * coverage,
        "expected_error": expected,
        "resolution": jnp.sum(solid * m * ray_res) / safe_denominator(jnp.sum(solid * m)),
        "coverage": coverage,
        "hard_coverage": jax.lax.stop_gradient(hard_cov),
        "mean_step_px": jnp.sum(weight[None] * step_px) / wsum / (spec.num_candidates - 1),
        "guess_error": jnp.asarray(guess, d.dtype),
        "candidates": d,
    }


def objective(layout: Layout, spec: DesignSpec) -> Array:
    """J (1/m, lower is better) of one layout, without the constraint penalty."""
    return objective_terms(layout, spec)["objective"]


def camera_counts(layout: Layout, spec: DesignSpec) -> Array:
    """(H, W) number of cameras that see each ray of ``spec.pano`` (0/1 visibility, the same
    test as ``hard_coverage``), for plots."""
    fov_m, occ_m, clr_m, *_ = _margins(layout, spec)
    v = _visibility(fov_m, occ_m, clr_m, spec, hard=True)
    return jnp.sum(v, axis=0).reshape(spec.pano.height, spec.pano.width)
