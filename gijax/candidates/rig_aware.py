r"""Rig-aware geometry-informed (GI) candidates: equal feature-displacement steps for a real rig.

Definition
----------
Let ``o`` be the rig's reference point (the panorama centre) and ``r`` a unit panorama ray. The
swept point at distance ``d`` is ``P(d) = o + d r``. Camera ``c`` (centre ``t_c``) sees it along
``P(d) - t_c = a + d r`` with ``a = o - t_c``. As ``d`` runs from infinity down to 0 that viewing
direction turns, inside the plane spanned by ``a`` and ``r``, from ``r`` towards ``a``; its angle
to ``r`` is the camera's parallax angle

.. math::  \varphi_{rc}(d) = \operatorname{atan2}(q, d + p), \quad p = a\cdot r,\;
           q = \lVert a \times r\rVert ,

strictly decreasing in ``d`` (for ``q > 0``). Because the direction stays in one plane and turns
monotonically, the angle between the viewing directions of two swept points is exactly the
difference of their parallax angles: the feature seen by camera ``c`` moves by
``phi(d_i) - phi(d_{i+1})`` radians when the candidate steps from ``d_i`` to ``d_{i+1}``.

Through the real projection ``pi_c`` this is a displacement in pixels; to first order it is the
angle times ``s_rc = || J_{pi_c}(R_c^T r) R_c^T e ||``, the camera's pixels per radian at the
feature's direction (the far end of the sweep) along the direction ``e`` in which the feature
moves (``a`` minus its component along ``r``, normalised). ``measure='pixels'`` (default) uses
these scales, so intrinsics and orientations enter; ``measure='angle'`` sets ``s = 1``.

Aggregation over panorama rays (a hemisphere grid, solid-angle weights ``omega_r``) and cameras:

.. math::  \Phi(d) = \frac{\sum_{r,c} W_{rc}\, s_{rc}\, \varphi_{rc}(d)}{\sum_{r,c} W_{rc}},
           \qquad W_{rc} = \omega_r\, v_{rc}\, m_r\, n_{rc}\, z_c

* ``v_rc``: camera ``c`` sees ``P(d)`` (valid projection inside the field of view and image, and
  the rig's self-occlusion mask) at every one of ``samples`` distances spread geometrically over
  ``[d_min, d_max]``;
* ``m_r``: at least two cameras see the ray that way (a ray seen by one camera cannot be matched);
* ``n_rc``: the swept segment never comes closer to camera ``c`` than ``d_min / 2`` (a ray that
  passes right next to a lens would make the angle jump by up to pi over a tiny range of ``d``);
* ``z_c``: the camera is not at the reference point (``|a| > 1e-6`` m): such a camera sees every
  swept point along the same ray and has no parallax; it still counts towards ``m_r``.

``Phi(d_i) - Phi(d_{i+1})`` is the weighted mean displacement of a step over all ray/camera
pairs (pixels, or radians). The rig-aware GI list makes the ``n - 1`` steps equal:

.. math::  \Phi(d_i) = \Phi(d_{min}) - \tfrac{i}{n-1}\,(\Phi(d_{min}) - \Phi(d_{max})).

Reduction to the closed form: with the reference at one camera of a two-camera rig and rays
perpendicular to the baseline ``b``, every counted term has ``p = 0`` and ``q = b``, so
``Phi(d) = S atan(b/d)`` for a constant ``S``; equal steps of ``Phi`` are equal steps of
``atan(b/d)``, which is exactly the paper's closed form. This holds because the aggregation is
*linear* in the angles (a weighted mean of cumulative angles), whatever the weights and scales;
an aggregation of squared or per-step-normalised displacements would not reduce exactly.

Solver and derivatives
----------------------
``Phi`` is smooth and strictly increasing in the inverse distance ``u = 1/d``, with the analytic
derivative ``dphi/du = q / ((1 + p u)^2 + (q u)^2)``. The solve has a fixed length: (1) ``Phi``
and ``Phi'`` on ``num_nodes`` nodes (evenly spaced in ``atan(b0 u)`` for the rig's mean
perpendicular offset ``b0``, where the closed form says ``Phi`` is nearly linear); (2) each
target is located in its node interval (a comparison count, no search loop) and solved on the
cubic Hermite interpolant by a few clamped Newton steps; (3) one exact Newton step on ``Phi``
clamped to that interval; (4) a final exact Newton step written as the implicit-function-theorem
update ``u = u* - (Phi(u*; theta) - y(theta)) / Phi'(u*)`` with ``u*`` and ``Phi'(u*)`` held
constant (``stop_gradient``). At the solution the step's value is a polish and its derivative is
``du/dtheta = -(dPhi/dtheta - dy/dtheta) / Phi'``: the exact implicit derivative for camera
translations, rotations and intrinsics (through the scales ``s``) and for ``d_min``, ``d_max``.

Why implicit rather than unrolled: the list is defined by ``Phi(u_i) = y_i`` alone, so the
derivative of the solution is fully determined by the implicit function theorem and costs one
evaluation of ``Phi``; backpropagating through the table and the Newton iterations would cost
several times more, would differentiate the approximation (the interpolant) rather than the
definition, and would be exact only to the extent that the iterations converged. The visibility
factors ``W`` are piecewise constant (their derivative is zero almost everywhere); a
perturbation that moves a ray across a mask or field-of-view boundary changes the list by a
jump of order (one ray's weight), which finite differences of small steps do not meet.
Second derivatives through the stop-gradient step are not exact.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from gijax.candidates.closed_form import _float_dtype
from gijax.candidates.validation import check_count, check_range, is_concrete
from gijax.geometry import cameras as cam_lib
from gijax.geometry.panorama import Panorama, lonlat_grid, ray_grid
from gijax.geometry.rig import Rig, map_cameras, project_rig_points

Array = jax.Array

DEFAULT_PANO = Panorama.hemisphere(8, 32)
"""Panorama rays the displacement is averaged over (256 rays; see docs/candidates.md for the
effect of the resolution)."""
MEASURES = ("pixels", "angle")
_NUM_NODES = 24
_HERMITE_ITERS = 4
_TINY = 1e-30


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RigTerms:
    """Ray/camera terms of the cumulative displacement, flattened to K = cameras x rays.

    along: (K,) ``p = (o - t_c) . r`` metres; perp: (K,) ``q = |(o - t_c) x r|`` metres;
    weight: (K,) ``W`` (solid angle times the 0/1 factors, 0 for excluded pairs);
    scale: (K,) ``s`` pixels per radian (ones for ``measure='angle'``).
    """

    along: Array
    perp: Array
    weight: Array
    scale: Array

    @property
    def coverage(self) -> Array:
        """Sum of the weights: 0 when no ray is seen by two cameras with parallax."""
        return jnp.sum(self.weight)


def _safe_norm(x: Array, axis=-1) -> Array:
    sq = jnp.sum(x * x, axis=axis)
    return jnp.sqrt(jnp.where(sq > _TINY, sq, _TINY))


def _safe_div(num: Array, den: Array) -> Array:
    ok = jnp.abs(den) > _TINY
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def _check_options(pano, measure: str, samples: int) -> None:
    if not isinstance(pano, Panorama):
        raise ValueError(f"pano must be a gijax Panorama; found {type(pano).__name__}")
    if measure not in MEASURES:
        raise ValueError(f"measure must be one of {MEASURES}; found measure={measure!r}")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 2:
        raise ValueError(f"samples must be an integer >= 2; found samples={samples!r}")


def _check_rays(rays) -> None:
    if rays is None or not is_concrete(rays):
        return
    r = np.asarray(rays, np.float64)
    if r.ndim != 2 or r.shape[1] != 3 or r.shape[0] == 0:
        raise ValueError(f"rays must be an (R, 3) array of directions; found shape {r.shape}")
    if not np.all(np.isfinite(r)) or np.any(np.linalg.norm(r, axis=1) == 0.0):
        raise ValueError("rays must be finite, non-zero directions")


def as_float_rig(rig: Rig) -> Rig:
    """The rig with its poses, reference and intrinsics in the default float dtype (float64 when
    x64 is on); masks are left as they are (they are only compared)."""
    dt = _float_dtype()
    cast = lambda x: jnp.asarray(x, dt) if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating) else x
    return rig.replace(cameras=jax.tree_util.tree_map(cast, rig.cameras),
                       rotations=cast(rig.rotations), translations=cast(rig.translations),
                       reference=cast(rig.reference))


def rig_terms(rig: Rig, d_min, d_max, pano: Panorama = DEFAULT_PANO, measure: str = "pixels",
              samples: int = 4, rays=None) -> RigTerms:
    """The ray/camera terms ``(p, q, W, s)`` of the cumulative displacement (pure, jit-able).

    ``rays``: optional (R, 3) rig-frame directions used instead of the panorama grid, with equal
    weights (for a partial view, or to study a single direction family).
    """
    dt = rig.translations.dtype
    if rays is None:
        rays = ray_grid(pano, dt).reshape(-1, 3)  # (R, 3)
        _, lat = lonlat_grid(pano, dt)
        dlat = (pano.lat_max - pano.lat_min) / pano.height
        solid = (jnp.cos(lat) * dlat * (2.0 * math.pi / pano.width)).reshape(-1)  # steradians
    else:
        rays = jnp.asarray(rays, dt).reshape(-1, 3)
        rays = rays / _safe_norm(rays)[:, None]
        solid = jnp.full(rays.shape[:1], 1.0 / rays.shape[0], dt)

    a = rig.reference[None, :] - rig.translations  # (C, 3)
    p = a @ rays.T  # (C, R)
    q = _safe_norm(jnp.cross(a[:, None, :], rays[None, :, :]))  # (C, R)

    # Visibility at distances spread geometrically over the range.
    frac = jnp.linspace(0.0, 1.0, samples, dtype=dt)
    ds = jnp.exp(jnp.log(d_min) + frac * (jnp.log(d_max) - jnp.log(d_min)))
    pts = rig.reference + ds[:, None, None] * rays[None]  # (S, R, 3)
    _, vis = project_rig_points(rig, jax.lax.stop_gradient(pts))  # (C, S, R)
    seen = jnp.all(vis, axis=1)  # (C, R)
    matched = jnp.sum(seen, axis=0) >= 2  # (R,)

    # Closest approach of the swept segment to the camera centre.
    d_star = jnp.clip(-p, d_min, d_max)
    closest = jnp.sqrt(q * q + (p + d_star) ** 2)
    clear = closest >= 0.5 * d_min
    parallax = _safe_norm(a) > 1e-6  # (C,)

    keep = seen & matched[None] & clear & parallax[:, None]
    weight = jnp.where(keep, solid[None], 0.0)

    if measure == "angle":
        scale = jnp.ones_like(q)
    else:
        move = _safe_div(a[:, None, :] - p[..., None] * rays[None], q[..., None])  # (C, R, 3)

        def px_per_rad(cam, rot, trans, mask, e):
            v_cam = rays @ rot  # R^T r for every ray
            e_cam = e @ rot
            _, tangent = jax.jvp(lambda x: cam_lib.project(cam, x)[0], (v_cam,), (e_cam,))
            return _safe_norm(tangent)

        scale = map_cameras(px_per_rad, rig, move)  # (C, R)
        scale = jnp.where(keep, scale, 0.0)
    return RigTerms(along=p.reshape(-1), perp=q.reshape(-1), weight=weight.reshape(-1),
                    scale=scale.reshape(-1))


def parallax_angles(terms: RigTerms, inv_d: Array) -> Array:
    """Per-term parallax angle (radians) at inverse distances ``inv_d`` (...,) -> (..., K)."""
    u = inv_d[..., None]
    return jnp.arctan2(terms.perp * u, 1.0 + terms.along * u)


def cumulative_displacement(terms: RigTerms, inv_d: Array) -> Array:
    """``Phi`` at inverse distances ``inv_d`` (...,) in 1/m -> (...,) pixels (or radians).

    Increasing in ``inv_d``; ``Phi(d_i) - Phi(d_{i+1})`` is the mean displacement of a step.
    """
    w = terms.weight * terms.scale / jnp.maximum(terms.coverage, _TINY)
    return parallax_angles(terms, inv_d) @ w


def cumulative_displacement_slope(terms: RigTerms, inv_d: Array) -> Array:
    """``dPhi/du`` at inverse distances ``inv_d`` (...,) -> (...,)."""
    u = inv_d[..., None]
    w = terms.weight * terms.scale / jnp.maximum(terms.coverage, _TINY)
    den = (1.0 + terms.along * u) ** 2 + (terms.perp * u) ** 2
    return (terms.perp / jnp.maximum(den, _TINY)) @ w


def _hermite_solve(un, fn, dn, y):
    """Solve the cubic Hermite interpolant of (un, fn, dn) for each target in y.

    Returns the root and the node interval [lo, hi] it lies in (shapes of y).
    """
    m = un.shape[0]
    j = jnp.clip(jnp.sum(fn[None, :] <= y[:, None], axis=-1) - 1, 0, m - 2)
    u0, u1, f0, f1, d0, d1 = un[j], un[j + 1], fn[j], fn[j + 1], dn[j], dn[j + 1]
    h = u1 - u0
    t = jnp.clip(_safe_div(y - f0, f1 - f0), 0.0, 1.0)

    def newton(_, t):
        t2, t3 = t * t, t * t * t
        val = ((2 * t3 - 3 * t2 + 1) * f0 + (t3 - 2 * t2 + t) * h * d0
               + (-2 * t3 + 3 * t2) * f1 + (t3 - t2) * h * d1)
        der = ((6 * t2 - 6 * t) * f0 + (3 * t2 - 4 * t + 1) * h * d0
               + (-6 * t2 + 6 * t) * f1 + (3 * t2 - 2 * t) * h * d1)
        der = jnp.where(der > _TINY, der, f1 - f0 + _TINY)
        return jnp.clip(t - (val - y) / der, 0.0, 1.0)

    t = jax.lax.fori_loop(0, _HERMITE_ITERS, newton, t)
    return u0 + t * h, u0, u1


def solve_equal_steps(terms: RigTerms, n: int, d_min, d_max, num_nodes: int = _NUM_NODES):
    """The n distances (ascending, metres) with equal steps of ``Phi``; pure and fixed-length.

    Differentiable by the implicit function theorem (see the module docstring). Returns NaN
    everywhere when ``terms.coverage`` is 0 (inside a trace there is no other way to signal it;
    the public :func:`rig_gi_candidates` raises before that can happen on concrete input).
    """
    dt = terms.along.dtype
    d_min = jnp.asarray(d_min, dt)
    d_max = jnp.asarray(d_max, dt)
    u_lo, u_hi = 1.0 / d_max, 1.0 / d_min

    def targets(tm):
        f_hi = cumulative_displacement(tm, u_hi)
        f_lo = cumulative_displacement(tm, u_lo)
        frac = jnp.linspace(0.0, 1.0, n, dtype=dt)[1:-1]
        return f_hi - frac * (f_hi - f_lo)  # descending in i, like u_i

    fixed = jax.lax.stop_gradient(terms)
    fixed_lo, fixed_hi = jax.lax.stop_gradient(u_lo), jax.lax.stop_gradient(u_hi)
    y_fixed = targets(fixed)
    # Nodes evenly spaced in atan(b0 u): nearly uniform steps of Phi for a single baseline b0.
    b0 = jnp.maximum(jnp.sum(fixed.weight * fixed.perp) / jnp.maximum(fixed.coverage, _TINY),
                     1e-6)
    th = jnp.linspace(jnp.arctan(b0 * fixed_lo), jnp.arctan(b0 * fixed_hi), num_nodes)
    un = (jnp.tan(th) / b0).at[0].set(fixed_lo).at[-1].set(fixed_hi)
    fn = cumulative_displacement(fixed, un)
    dn = cumulative_displacement_slope(fixed, un)
    u, lo, hi = _hermite_solve(un, fn, dn, y_fixed)

    def newton_step(tm, y, u):
        slope = jax.lax.stop_gradient(cumulative_displacement_slope(fixed, u))
        slope = jnp.where(slope > _TINY, slope, 1.0)
        return u - (cumulative_displacement(tm, u) - y) / slope

    u = jnp.clip(newton_step(fixed, y_fixed, u), lo, hi)
    u = jax.lax.stop_gradient(u)
    u = newton_step(terms, targets(terms), u)  # implicit-function-theorem step
    d = jnp.concatenate([d_min[None], 1.0 / u, d_max[None]])
    return jnp.where(terms.coverage > 0.0, d, jnp.nan)


@functools.partial(jax.jit, static_argnames=("n", "pano", "measure", "samples"))
def _rig_gi_jit(rig, d_min, d_max, rays, *, n, pano, measure, samples):
    terms = rig_terms(rig, d_min, d_max, pano, measure, samples, rays)
    return solve_equal_steps(terms, n, d_min, d_max), terms.coverage


def _no_coverage_error(rig: Rig, d_min, d_max) -> ValueError:
    return ValueError(
        f"rig: no panorama ray between d_min={float(d_min)} m and d_max={float(d_max)} m is seen "
        f"by two cameras with parallax (cameras {list(rig.names)} at "
        f"{np.round(np.asarray(rig.translations), 4).tolist()}, reference "
        f"{np.round(np.asarray(rig.reference), 4).tolist()}); GI candidates need overlapping "
        "views from distinct camera centres")


def rig_gi_candidates(rig: Rig, n: int, d_min=0.5, d_max=100.0, *, pano: Panorama = DEFAULT_PANO,
                      measure: str = "pixels", samples: int = 4, rays=None) -> Array:
    """Rig-aware GI candidates: (n,) ascending metres with equal mean feature displacement steps.

    Args:
      rig: the rig (camera models, poses, reference point, masks).
      n: number of candidates (>= 2).
      d_min, d_max: the range in metres, 0 < d_min < d_max; the ends of the list.
      pano: panorama rays the displacement is averaged over (hemisphere grid).
      measure: 'pixels' (angle times the projection's pixels per radian) or 'angle' (radians).
      samples: distances at which visibility is tested.
      rays: optional (R, 3) rig-frame directions replacing the panorama grid (equal weights).

    Raises ValueError for bad arguments and for a rig where no ray is seen by two cameras with
    parallax. Jit-able and differentiable (see the module docstring); under a trace the rig
    check cannot raise and such a rig gives NaN.
    """
    n = check_count(n)
    check_range(d_min, d_max)
    _check_options(pano, measure, samples)
    _check_rays(rays)
    d, coverage = _rig_gi_jit(as_float_rig(rig), d_min, d_max, rays, n=n, pano=pano,
                              measure=measure, samples=samples)
    if is_concrete(coverage) and not float(coverage) > 0.0:
        raise _no_coverage_error(rig, d_min, d_max)
    return d


def fit_closed_form_baseline(candidates, d_min=None, d_max=None) -> float:
    """The baseline b (m) whose closed-form GI list best matches ``candidates`` in log distance.

    Minimises ``sum_i (log d_i(b) - log c_i)^2`` over b in ``[1e-3 d_min, 10 d_max]`` (a grid on
    log b, then a bounded scalar search; concrete values, not traced). As ``b -> 0`` the closed
    form tends to the EV list; a list at least as linear in inverse distance as EV fits best at
    the lower end of the range and gets 0.0 ("EV-like").
    """
    from scipy.optimize import minimize_scalar

    c = np.asarray(candidates, np.float64)
    if c.ndim != 1 or c.size < 2 or not np.all(np.isfinite(c)) or np.any(np.diff(c) <= 0):
        raise ValueError(f"candidates must be a finite ascending 1-D list of >= 2 distances; "
                         f"found shape {c.shape}")
    lo = c[0] if d_min is None else float(d_min)
    hi = c[-1] if d_max is None else float(d_max)
    theta_frac = np.linspace(0.0, 1.0, c.size)

    def loss(log_b):
        b = math.exp(log_b)
        th = math.atan(b / lo) + theta_frac * (math.atan(b / hi) - math.atan(b / lo))
        return float(np.sum((np.log(b / np.tan(th)) - np.log(c)) ** 2))

    # Coarse grid first (the loss need not be unimodal over six decades), then a bounded refine.
    grid = np.linspace(math.log(1e-3 * lo), math.log(10.0 * hi), 241)
    k = int(np.argmin([loss(g) for g in grid]))
    if k == 0:
        # The b -> 0 limit of the closed form is the EV list; this list is at least that linear.
        return 0.0
    lo_g, hi_g = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    res = minimize_scalar(loss, bounds=(lo_g, hi_g), method="bounded", options={"xatol": 1e-10})
    return float(math.exp(res.x))


def effective_baseline(rig: Rig, n: int = 16, d_min=0.5, d_max=100.0, **opts) -> float:
    """The baseline (m) whose closed-form GI list best matches the rig-aware list of n entries.

    0.0 means the rig-aware list is EV-like (see :func:`fit_closed_form_baseline`).
    """
    d = rig_gi_candidates(rig, n, d_min, d_max, **opts)
    return fit_closed_form_baseline(d, d_min, d_max)
