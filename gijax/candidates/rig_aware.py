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

from gijax.candidates import parallax as par
from gijax.candidates.closed_form import _float_dtype
from gijax.candidates.validation import (check_count, check_range, guard_candidates,
                                         is_concrete, require)
from gijax.geometry.panorama import Panorama
from gijax.geometry.panorama_frame import panorama_rotation
from gijax.geometry.rig import Rig, map_cameras, project_rig_points
from gijax.numerics import guard_floor, safe_denominator, safe_div, unit

Array = jax.Array

DEFAULT_PANO = Panorama.hemisphere(8, 32)
"""Panorama rays the displacement is averaged over (256 rays; see docs/candidates.md for the
effect of the resolution)."""
MEASURES = ("pixels", "angle")
MEASURE_UNITS = {"pixels": "px", "angle": "rad"}
"""Unit of the displacements of each measure (for labels and reports)."""
_NUM_NODES = 24
_HERMITE_ITERS = 4
# A camera closer than this to the reference point (metres) sees every swept point along the
# same ray: it has no parallax.
_MIN_OFFSET = 1e-6


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


def _check_options(pano, measure: str, samples: int) -> None:
    if not isinstance(pano, Panorama):
        raise ValueError(f"pano must be a gijax Panorama; found {type(pano).__name__}")
    if measure not in MEASURES:
        raise ValueError(f"measure must be one of {MEASURES}; found measure={measure!r}")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 2:
        raise ValueError(f"samples must be an integer >= 2; found samples={samples!r}")


def _check_rays(rays) -> None:
    """(R, 3) finite non-zero directions; the shape always, the values when concrete."""
    if rays is None:
        return
    shape = tuple(np.shape(rays))
    if len(shape) != 2 or shape[1] != 3 or shape[0] == 0:
        raise ValueError(f"rays must be an (R, 3) array of directions; found shape {shape}")
    if not is_concrete(rays):
        r = jnp.asarray(rays)
        require(jnp.all(jnp.isfinite(r)) & jnp.all(jnp.sum(r * r, axis=1) > 0),
                "rays must be finite, non-zero directions; found {r}", r=r)
        return
    r = np.asarray(rays, np.float64)
    if not np.all(np.isfinite(r)) or np.any(np.linalg.norm(r, axis=1) == 0.0):
        raise ValueError("rays must be finite, non-zero directions")


def as_float_rig(rig: Rig) -> Rig:
    """The rig with its poses, reference and intrinsics in the default float dtype (float64 when
    x64 is on); masks are left as they are (they are only compared)."""
    dt = _float_dtype()
    cast = lambda x: jnp.asarray(x, dt) if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating) else x
    return rig.replace(cameras=jax.tree_util.tree_map(cast, rig.cameras),
                       rotations=cast(rig.rotations), translations=cast(rig.translations),
                       reference=cast(rig.reference),
                       panorama_rotation=cast(panorama_rotation(rig)))


@functools.partial(jax.jit, static_argnames=("pano", "measure", "samples"))
def rig_terms(rig: Rig, d_min, d_max, pano: Panorama = DEFAULT_PANO, measure: str = "pixels",
              samples: int = 4, rays=None) -> RigTerms:
    """The ray/camera terms ``(p, q, W, s)`` of the cumulative displacement (pure; jitted, with
    ``pano``, ``measure`` and ``samples`` static, so that eager callers run one program).

    ``rays``: optional (R, 3) rig-frame directions used instead of the panorama grid, with equal
    weights (for a partial view, or to study a single direction family).
    """
    dt = rig.translations.dtype
    if rays is None:
        rays, solid = par.rays_and_solid_angles(pano, dt)
        # The panorama's rays, oriented by the rig's panorama frame.
        rays = rays @ panorama_rotation(rig).astype(dt).T
    else:
        rays = unit(jnp.asarray(rays, dt).reshape(-1, 3))
        solid = jnp.full(rays.shape[:1], 1.0 / rays.shape[0], dt)

    a, p, q = par.parallax_offsets(rig.reference, rig.translations, rays)  # (C, 3), (C, R)

    # Visibility at distances spread geometrically over the range.
    ds = par.sample_distances(d_min, d_max, samples, dt)
    pts = rig.reference + ds[:, None, None] * rays[None]  # (S, R, 3)
    _, vis = project_rig_points(rig, jax.lax.stop_gradient(pts))  # (C, S, R)
    seen = jnp.all(vis, axis=1)  # (C, R)
    matched = jnp.sum(seen, axis=0) >= 2  # (R,)

    clear = par.closest_approach(p, q, d_min, d_max) >= 0.5 * d_min
    parallax = jnp.sum(a * a, axis=-1) > _MIN_OFFSET**2  # (C,)

    keep = seen & matched[None] & clear & parallax[:, None]
    weight = jnp.where(keep, solid[None], 0.0)

    if measure == "angle":
        scale = jnp.ones_like(q)
    else:
        move = par.motion_directions(a, p, q, rays)  # (C, R, 3)
        scale = map_cameras(lambda cam, rot, trans, mask, e: par.pixels_per_radian(
            cam, rot, rays, e), rig, move)  # (C, R)
        scale = jnp.where(keep, scale, 0.0)
    return RigTerms(along=p.reshape(-1), perp=q.reshape(-1), weight=weight.reshape(-1),
                    scale=scale.reshape(-1))


def parallax_angles(terms: RigTerms, inv_d: Array) -> Array:
    """Per-term parallax angle (radians) at inverse distances ``inv_d`` (...,) -> (..., K)."""
    return par.parallax_angle(terms.along, terms.perp, jnp.asarray(inv_d)[..., None])


def _normalised_weights(terms: RigTerms) -> Array:
    return terms.weight * terms.scale / safe_denominator(terms.coverage)


def cumulative_displacement(terms: RigTerms, inv_d: Array) -> Array:
    """``Phi`` at inverse distances ``inv_d`` (...,) in 1/m -> (...,) pixels (or radians).

    Increasing in ``inv_d``; ``Phi(d_i) - Phi(d_{i+1})`` is the mean displacement of a step.
    """
    return parallax_angles(terms, inv_d) @ _normalised_weights(terms)


def cumulative_displacement_slope(terms: RigTerms, inv_d: Array) -> Array:
    """``dPhi/du`` at inverse distances ``inv_d`` (...,) -> (...,)."""
    u = jnp.asarray(inv_d)[..., None]
    den = (1.0 + terms.along * u) ** 2 + (terms.perp * u) ** 2
    return safe_div(terms.perp, den) @ _normalised_weights(terms)


def _hermite_solve(un, fn, dn, y):
    """Solve the cubic Hermite interpolant of (un, fn, dn) for each target in y.

    Returns the root and the node interval [lo, hi] it lies in (shapes of y).
    """
    m = un.shape[0]
    j = jnp.clip(jnp.sum(fn[None, :] <= y[:, None], axis=-1) - 1, 0, m - 2)
    u0, u1, f0, f1, d0, d1 = un[j], un[j + 1], fn[j], fn[j + 1], dn[j], dn[j + 1]
    h = u1 - u0
    t = jnp.clip(safe_div(y - f0, f1 - f0), 0.0, 1.0)

    def newton(_, t):
        t2, t3 = t * t, t * t * t
        val = ((2 * t3 - 3 * t2 + 1) * f0 + (t3 - 2 * t2 + t) * h * d0
               + (-2 * t3 + 3 * t2) * f1 + (t3 - t2) * h * d1)
        der = ((6 * t2 - 6 * t) * f0 + (3 * t2 - 4 * t + 1) * h * d0
               + (-6 * t2 + 6 * t) * f1 + (3 * t2 - 2 * t) * h * d1)
        # A non-increasing interpolant (a rounding artefact) falls back to the secant slope.
        eps = guard_floor(der)
        der = jnp.where(der > eps, der, f1 - f0 + eps)
        return jnp.clip(t - (val - y) / der, 0.0, 1.0)

    t = jax.lax.fori_loop(0, _HERMITE_ITERS, newton, t)
    return u0 + t * h, u0, u1


def solve_equal_steps(terms: RigTerms, n: int, d_min, d_max, num_nodes: int = _NUM_NODES):
    """The n distances (ascending, metres) with equal steps of ``Phi``; pure and fixed-length.

    Differentiable by the implicit function theorem (see the module docstring). Returns NaN
    everywhere when ``terms.coverage`` is 0 (the value cannot raise; the public
    :func:`rig_gi_candidates` raises on concrete input), with finite gradients.
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
    b0 = jnp.maximum(jnp.sum(fixed.weight * fixed.perp) / safe_denominator(fixed.coverage),
                     _MIN_OFFSET)
    th = jnp.linspace(jnp.arctan(b0 * fixed_lo), jnp.arctan(b0 * fixed_hi), num_nodes)
    un = (jnp.tan(th) / b0).at[0].set(fixed_lo).at[-1].set(fixed_hi)
    fn = cumulative_displacement(fixed, un)
    dn = cumulative_displacement_slope(fixed, un)
    u, lo, hi = _hermite_solve(un, fn, dn, y_fixed)

    def newton_step(tm, y, u):
        slope = jax.lax.stop_gradient(cumulative_displacement_slope(fixed, u))
        slope = jnp.where(slope > guard_floor(slope), slope, 1.0)
        return u - (cumulative_displacement(tm, u) - y) / slope

    u = jnp.clip(newton_step(fixed, y_fixed, u), lo, hi)
    u = jax.lax.stop_gradient(u)
    u = newton_step(terms, targets(terms), u)  # implicit-function-theorem step
    d = jnp.concatenate([d_min[None], 1.0 / u, d_max[None]])
    return jnp.where(terms.coverage > 0.0, d, jnp.nan)


@functools.partial(jax.jit, static_argnames=("n", "pano", "measure", "samples"))
def _rig_gi_jit(rig, d_min, d_max, rays, *, n, pano, measure, samples):
    # One compiled program per (n, pano, measure, samples) for eager callers.
    terms = rig_terms(rig, d_min, d_max, pano, measure, samples, rays)
    return solve_equal_steps(terms, n, d_min, d_max), terms.coverage


def require_coverage(coverage, rig: Rig, d_min, d_max) -> None:
    """ValueError when ``coverage`` (:attr:`RigTerms.coverage`) is 0 and every input is concrete;
    a checkify debug check under a trace (where the candidates come back as NaN instead)."""
    if is_concrete(coverage, rig, d_min, d_max):
        where = (f" (cameras {list(rig.names)} at "
                 f"{np.round(np.asarray(rig.translations), 4).tolist()}, reference "
                 f"{np.round(np.asarray(rig.reference), 4).tolist()})")
        range_ = f"between d_min={float(d_min)} m and d_max={float(d_max)} m "
    else:
        where = f" (cameras {list(rig.names)})"
        range_ = ""
    require(coverage > 0.0, "rig: no panorama ray " + range_ + "is seen by two cameras with "
            "parallax" + where + "; GI candidates need overlapping views from distinct camera "
            "centres", inputs=(rig, d_min, d_max))


def _require_finite_rig(rig: Rig) -> None:
    """ValueError (checkify under a trace) when a pose, the reference point or an intrinsic of
    ``rig`` is NaN or infinite: the candidates would come back as NaN."""
    leaves = [x for x in jax.tree_util.tree_leaves((rig.rotations, rig.translations,
                                                    rig.reference, rig.cameras))
              if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating)]
    ok = jnp.all(jnp.asarray([jnp.all(jnp.isfinite(x)) for x in leaves]))
    require(ok, "rig: a camera pose, the reference point or an intrinsic parameter is NaN or "
            "infinite (cameras " + ", ".join(rig.names).replace("{", "{{").replace("}", "}}")
            + "); GI candidates need a finite "
            "calibration", inputs=(rig,))


def rig_gi_candidates(rig: Rig, n: int, d_min=0.5, d_max=100.0, *, pano: Panorama = DEFAULT_PANO,
                      measure: str = "pixels", samples: int = 4, rays=None) -> Array:
    """Rig-aware GI candidates: (n,) ascending metres with equal mean feature displacement steps.

    Args:
      rig: the rig (camera models, poses, reference point, masks).
      n: number of candidates (>= 2); static.
      d_min, d_max: the range in metres, 0 < d_min < d_max; the ends of the list.
      pano: panorama rays the displacement is averaged over (hemisphere grid); static.
      measure: 'pixels' (angle times the projection's pixels per radian) or 'angle' (radians).
      samples: distances at which visibility is tested; static.
      rays: optional (R, 3) rig-frame directions replacing the panorama grid (equal weights).

    Traceable (jit, vmap, grad over the rig's poses and intrinsics, d_min, d_max; see the module
    docstring for the derivative). On concrete input, bad arguments and a rig where no ray is
    seen by two cameras with parallax raise ValueError; under a trace such a rig gives NaN and
    the value checks are checkify debug checks (``checkify.checkify`` turns them into errors).
    """
    n = check_count(n)
    check_range(d_min, d_max)
    _check_options(pano, measure, samples)
    _check_rays(rays)
    rig = as_float_rig(rig)
    _require_finite_rig(rig)
    d, coverage = _rig_gi_jit(rig, d_min, d_max, rays, n=n, pano=pano, measure=measure,
                              samples=samples)
    require_coverage(coverage, rig, d_min, d_max)
    return d


# Grid on log b of the closed-form fit, and golden-section steps refining its best cell (each
# shrinks the bracket by 0.618: 60 take a 0.12-wide cell below 1e-13 in log b).
_FIT_GRID = 241
_FIT_GOLDEN_STEPS = 60


def _closed_form_misfit(log_b, log_c, lo, hi):
    """``sum_i (log d_i(b) - log c_i)^2`` of the closed-form list for baseline ``exp(log_b)``."""
    b = jnp.exp(log_b)
    frac = jnp.linspace(0.0, 1.0, log_c.shape[0], dtype=log_c.dtype)
    th = jnp.arctan(b / lo) + frac * (jnp.arctan(b / hi) - jnp.arctan(b / lo))
    return jnp.sum((log_b - jnp.log(jnp.tan(th)) - log_c) ** 2)


def fit_closed_form_baseline(candidates, d_min=None, d_max=None) -> Array:
    """The baseline b (m) whose closed-form GI list best matches ``candidates`` in log distance.

    Minimises ``sum_i (log d_i(b) - log c_i)^2`` over b in ``[1e-3 d_min, 10 d_max]``: a grid on
    log b (the misfit need not be unimodal over six decades), then golden-section steps in the
    best grid cell, then one Newton step on the misfit's derivative written so that its
    gradient is the implicit derivative ``db/dc`` (as in :func:`solve_equal_steps`). As
    ``b -> 0`` the closed form tends to the EV list; a list at least as linear in inverse
    distance as EV fits best at the lower end of the range and gets 0.0 ("EV-like", zero
    gradient). ``d_min``, ``d_max`` default to the list's ends. A list with a NaN (a rig
    without coverage, under a trace) gives NaN.

    Traceable (jit, vmap, grad in the candidates and the range); the list is checked eagerly
    when concrete, by a checkify debug check when traced.
    """
    guard_candidates(candidates)
    c = jnp.asarray(candidates, _float_dtype())
    lo = c[0] if d_min is None else d_min
    hi = c[-1] if d_max is None else d_max
    return _fit_closed_form(c, jnp.asarray(lo, c.dtype), jnp.asarray(hi, c.dtype))


@jax.jit
def _fit_closed_form(c, lo, hi):
    log_c = jnp.log(c)
    misfit = lambda lb: _closed_form_misfit(lb, log_c, lo, hi)  # noqa: E731
    fixed = jax.lax.stop_gradient((log_c, lo, hi))
    misfit_fixed = lambda lb: _closed_form_misfit(lb, *fixed)  # noqa: E731

    grid = jnp.linspace(jnp.log(1e-3 * fixed[1]), jnp.log(10.0 * fixed[2]), _FIT_GRID)
    k = jnp.argmin(jax.vmap(misfit_fixed)(grid))
    golden = (math.sqrt(5.0) - 1.0) / 2.0

    def shrink(_, ab):
        a, b = ab
        x1, x2 = b - golden * (b - a), a + golden * (b - a)
        left = misfit_fixed(x1) < misfit_fixed(x2)
        return jnp.where(left, a, x1), jnp.where(left, x2, b)

    a, b = jax.lax.fori_loop(0, _FIT_GOLDEN_STEPS, shrink,
                             (grid[jnp.maximum(k - 1, 0)], grid[jnp.minimum(k + 1, _FIT_GRID - 1)]))
    best = jax.lax.stop_gradient(0.5 * (a + b))
    curvature = jax.grad(jax.grad(misfit_fixed))(best)
    curvature = jnp.where(curvature > guard_floor(curvature), curvature, 1.0)
    log_b = best - jax.grad(misfit)(best) / curvature  # value: best; gradient: implicit
    b = jnp.where(k == 0, 0.0, jnp.exp(log_b))
    # A NaN list (a rig without coverage under a trace) has no fit.
    return jnp.where(jnp.all(jnp.isfinite(c)), b, jnp.nan)


def effective_baseline(rig: Rig, n: int = 16, d_min=0.5, d_max=100.0, **opts) -> Array:
    """The baseline (m) whose closed-form GI list best matches the rig-aware list of n entries.

    0.0 means the rig-aware list is EV-like (see :func:`fit_closed_form_baseline`). Traceable
    like :func:`rig_gi_candidates`; ``opts`` go to it.
    """
    d = rig_gi_candidates(rig, n, d_min, d_max, **opts)
    return fit_closed_form_baseline(d, d_min, d_max)
