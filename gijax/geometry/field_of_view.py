"""Each camera's true field of view: the lens model's own limit, and what the image holds of it.

Every angle here is a full cone angle around the optical axis (+z) in radians, like ``cam.fov``:
a ray is inside when its angle to +z is at most half of it. ``cam.fov`` itself is only a cone
the user may set (360 degrees by default, and for every calibration import); it says nothing
about the lens. :func:`field_of_view` gives the three angles that do:

* ``model``: the widest cone on which the camera model's ``project`` accepts rays, from the
  intrinsics alone (no image size, no ``cam.fov``). Closed forms, from the validity condition
  in :mod:`gijax.geometry.cameras` written for a unit ray at angle ``theta`` to +z, i.e.
  ``z = cos(theta)``, ``x^2 + y^2 = sin(theta)^2``:

  - Double Sphere: ``project`` needs ``z > -w2 d1`` (Usenko et al. 2018, as in basalt), so
    ``cos(theta) > -w2`` and the limit is ``2 arccos(-w2)``;
    ``w1 = min(alpha, 1 - alpha) / max(alpha, 1 - alpha)``,
    ``w2 = (w1 + xi) / sqrt(2 w1 xi + xi^2 + 1)``. ``|w2| <= 1`` always, since
    ``(w1 + xi)^2 <= 1 + 2 w1 xi + xi^2`` is ``w1^2 <= 1``. The paper's calibration
    (xi = -0.203, alpha = 0.589) gives 249.3 degrees.
  - EUCM: ``z > -w rho`` with ``rho = sqrt(beta (x^2 + y^2) + z^2)``. Every ray in front
    passes; behind, with ``theta = 90 deg + psi``, squaring gives
    ``(1 - w^2) sin(psi)^2 < w^2 beta cos(psi)^2``, so the limit is
    ``2 (90 deg + atan2(w sqrt(beta), sqrt(1 - w^2)))``. Double Sphere with xi = 0 is EUCM with
    beta = 1, and the two forms agree there (``arccos(-w) = 90 deg + arcsin(w)``).
  - equidistant (``r = f theta``): the radius grows up to the backward axis, which alone has no
    direction in the image; the limit is 360 degrees.
  - Kannala-Brandt: ``project`` accepts a ray while ``d theta_d / d theta > 0``; past the first
    angle where the radius stops increasing, two directions share a pixel, so the limit is
    twice that angle (360 degrees when the radius grows all the way to 180 degrees). The
    derivative is a quartic in ``theta^2`` with no closed form worth having: its first sign
    change is found on a fixed grid of :data:`KB_GRID` angles and refined by
    :data:`KB_BISECTIONS` bisection steps (a dip of the derivative below zero narrower than
    one grid step, 180 / KB_GRID degrees, would be missed).

  - Unified (Mei 2007, Kalibr ``omni`` + ``radtan``): ``project`` needs ``z > -w |p|`` with
    ``w = xi`` for ``xi <= 1`` and ``1 / xi`` above (the normalised radius
    ``sin(theta) / (cos(theta) + xi)`` has derivative ``(1 + xi cos(theta)) / (...)^2``, which
    vanishes at ``cos(theta) = -1 / xi``), so ``arccos(-w)``; and an undistorted radius below
    the radial distortion's fold (the first positive root ``s`` of
    ``1 + 3 k1 s + 5 k2 s^2``, ``s = r^2``), whose angle is that of the lifted point
    ``cos(theta) = f - xi``, ``sin(theta) = f r``, ``f = (xi + sqrt(1 + (1 - xi^2) s)) /
    (1 + s)``. The limit is twice the smaller of the two. The tangential terms p1, p2 are
    left out of the domain. They also break the radial symmetry the image bounds below rely
    on; those take the angle of the exact foot and corner pixels (``unproject`` includes p1,
    p2), and p1, p2 move the side's point of smallest angle away from the foot by O(p), which
    changes the smallest angle itself only by O(p^2); against a dense ray sweep, a cropped
    1280 x 1024 image with |p1|, |p2| up to 1e-3 differs by below 5e-5 rad (0.003 deg).

  Where a model's radius diverges at its limit (EUCM with alpha < 0.5; alpha = 0.5 with
  xi = 0, whose limit is the backward axis), ``project`` also refuses pixels whose denominator
  is below 1e-6 of the point's distance, up to about 0.1 degree (half-angle) before the
  limit; no real image reaches that far out.

  gijax has no plain pinhole model (Kalibr's pinhole + equidistant is Kannala-Brandt); a lens
  whose model limit is wider than its sensor is bounded by the image, below.

* ``inscribed``: the widest cone around the axis that the image holds completely: the image
  edge nearest the principal point. Every model is radially symmetric in normalised
  coordinates ``((u - cx) / fx, (v - cy) / fy)`` and its angle grows with the normalised radius,
  so that edge is the foot of the perpendicular from the principal point to the nearest of the
  image's four sides (u = -0.5, u = W - 0.5, v = -0.5, v = H - 0.5). 0 when the principal point
  lies outside the image.
* ``effective``: the widest angle any pixel sees: the image corner farthest from the principal
  point, or the model limit where that corner lies past it (a circular fisheye whose image
  circle fits in the sensor).

``inscribed`` and ``effective`` are also bounded by ``cam.fov``. Angles at the image edge come
from :func:`gijax.geometry.cameras.unproject` (the one inverse of each model); an edge pixel
outside the model's domain is past the lens limit, so the limit applies there.

All of it is pure and traceable (jit; vmap over stacked cameras of one model), except
:func:`describe_field_of_view`, which formats concrete values.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp

from gijax.geometry import cameras as cam_lib
from gijax.numerics import safe_div, safe_sqrt

Array = jax.Array

# Kannala-Brandt: samples of the radius derivative on [0, pi], then bisection steps in the
# bracket of its first sign change. 1024 samples put the grid step at 0.18 degrees; 40 halvings
# of that step are far below float32 (and float64) resolution of the angle.
KB_GRID = 1024
KB_BISECTIONS = 40


@dataclasses.dataclass(frozen=True)
class FieldOfView:
    """Full cone angles around the optical axis, radians (module docstring).

    Attributes:
      model: the camera model's own limit, from the intrinsics alone.
      inscribed: the widest cone the image holds completely (nearest image edge).
      effective: the widest angle any pixel of the image sees.
    """

    model: Array
    inscribed: Array
    effective: Array


jax.tree_util.register_dataclass(FieldOfView, data_fields=["model", "inscribed", "effective"],
                                 meta_fields=[])


def _ds_half(cam) -> Array:
    alpha, xi = cam.alpha, cam.xi
    w1 = jnp.minimum(alpha, 1.0 - alpha) / jnp.maximum(alpha, 1.0 - alpha)
    w2 = (w1 + xi) / safe_sqrt(2.0 * w1 * xi + xi * xi + 1.0)
    # arccos(-w2) as an atan2: |w2| <= 1 in exact arithmetic, and the guarded root keeps the
    # gradient finite at alpha = 0.5, where w2 = 1 and the limit is the backward axis.
    return jnp.arctan2(safe_sqrt(1.0 - w2 * w2), -w2)


def _eucm_half(cam) -> Array:
    alpha = cam.alpha
    w = jnp.minimum(alpha, 1.0 - alpha) / jnp.maximum(alpha, 1.0 - alpha)
    # Guarded roots: at alpha = 0.5 (w = 1) the limit is the backward axis and sqrt(1 - w^2)
    # is 0, where a plain root's gradient is infinite.
    return 0.5 * jnp.pi + jnp.arctan2(w * safe_sqrt(cam.beta), safe_sqrt(1.0 - w * w))


def _equidistant_half(cam) -> Array:
    return jnp.full_like(cam.fx, jnp.pi)


def _kb_half(cam) -> Array:
    def slope(theta):
        # The model's own radius polynomial and its derivative: one definition of the lens.
        return cam._distort(theta)[1]

    dtype = jnp.result_type(cam.k1, jnp.float32)
    grid = jnp.linspace(0.0, jnp.pi, KB_GRID + 1, dtype=dtype)
    s = slope(grid)
    falls = s <= 0.0
    # slope(0) = 1, so a first non-positive sample has a positive one before it.
    first = jnp.argmax(falls)
    lo0, hi0 = grid[jnp.maximum(first - 1, 0)], grid[first]

    def halve(_, bracket):
        lo, hi = bracket
        mid = 0.5 * (lo + hi)
        up = slope(mid) > 0.0
        return jnp.where(up, mid, lo), jnp.where(up, hi, mid)

    lo, _ = jax.lax.fori_loop(0, KB_BISECTIONS, halve, (lo0, hi0))
    # One Newton step from the (constant) bisection result: the value stays the root, and the
    # gradient in the intrinsics becomes the implicit one, -(ds/dk) / (ds/dtheta), which the
    # comparisons of bisection alone would not give.
    root = jax.lax.stop_gradient(lo)
    s_root, ds_root = jax.jvp(slope, (root,), (jnp.ones_like(root),))
    root = root - safe_div(s_root, ds_root)
    return jnp.where(jnp.any(falls), root, jnp.asarray(jnp.pi, dtype))


def _unified_half(cam) -> Array:
    xi = cam.xi
    # The sphere's projection grows with the angle while cos(theta) > -w.
    w = jnp.minimum(xi, 1.0 / jnp.maximum(xi, 1.0))
    sphere = jnp.arctan2(safe_sqrt(1.0 - w * w), -w)
    # The radial distortion's fold at r^2 = s, lifted to the sphere as unproject does: the
    # ray of undistorted radius r has cos(theta) = factor - xi, sin(theta) = factor r.
    den, folds = cam._fold_denominator()
    s = 2.0 / jnp.where(folds, den, 1.0)
    lift = 1.0 + (1.0 - xi * xi) * s
    factor = (xi + safe_sqrt(lift)) / (1.0 + s)
    fold = jnp.arctan2(factor * safe_sqrt(s), factor - xi)
    # For xi > 1 a fold past the sphere's rim (lift < 0) is never reached.
    return jnp.where(folds & (lift > 0.0), jnp.minimum(fold, sphere), sphere)


_HALF_ANGLE = {
    cam_lib.DoubleSphere: _ds_half,
    cam_lib.EUCM: _eucm_half,
    cam_lib.Equidistant: _equidistant_half,
    cam_lib.KannalaBrandt: _kb_half,
    cam_lib.Unified: _unified_half,
}


def model_limit(cam) -> Array:
    """The camera model's own field of view: full cone angle in radians (module docstring)."""
    return 2.0 * _HALF_ANGLE[type(cam)](cam)


def _edge_half_angles(cam, pixels: Array, half_model: Array) -> Array:
    """Angle to +z of each pixel's ray, or the model's half-angle where the pixel lies past the
    lens limit (outside the model's domain, or unprojected beyond it)."""
    # unproject also applies cam.fov; lift it so that only the model's domain decides here.
    open_cam = dataclasses.replace(cam, fov=jnp.full_like(cam.fov, 2.0 * jnp.pi))
    rays, valid = cam_lib.unproject(open_cam, pixels)
    theta = jnp.arctan2(jnp.hypot(rays[..., 0], rays[..., 1]), rays[..., 2])
    return jnp.minimum(jnp.where(valid, theta, half_model), half_model)


def field_of_view(cam) -> FieldOfView:
    """The model limit, the inscribed and the effective field of view of one camera (full cone
    angles, radians; module docstring)."""
    half_model = _HALF_ANGLE[type(cam)](cam)
    left, top = -0.5, -0.5
    right, bottom = cam.width - 0.5, cam.height - 0.5
    cu = jnp.clip(cam.cx, left, right)
    cv = jnp.clip(cam.cy, top, bottom)
    feet = jnp.stack([jnp.stack([jnp.full_like(cv, left), cv]),
                      jnp.stack([jnp.full_like(cv, right), cv]),
                      jnp.stack([cu, jnp.full_like(cu, top)]),
                      jnp.stack([cu, jnp.full_like(cu, bottom)])])
    corners = jnp.stack([jnp.stack([jnp.full_like(cam.cx, u), jnp.full_like(cam.cy, v)])
                         for u in (left, right) for v in (top, bottom)])
    inside = (cam.cx > left) & (cam.cx < right) & (cam.cy > top) & (cam.cy < bottom)
    half_cone = 0.5 * cam.fov
    inscribed = jnp.min(_edge_half_angles(cam, feet, half_model))
    inscribed = jnp.where(inside, jnp.minimum(inscribed, half_cone), 0.0)
    effective = jnp.minimum(jnp.max(_edge_half_angles(cam, corners, half_model)), half_cone)
    return FieldOfView(model=2.0 * half_model, inscribed=2.0 * inscribed,
                       effective=2.0 * effective)


_field_of_view_jit = jax.jit(field_of_view)


def mask_field_of_view(cam, mask: Array) -> Array:
    """The widest angle a valid pixel of ``mask`` sees: full cone angle in radians.

    ``mask`` is (H, W) at the camera's resolution, nonzero = valid; pixel centres sit at
    integer coordinates (the image's sides at -0.5 and W - 0.5, as in :func:`field_of_view`).
    A calibration import leaves ``cam.fov`` at 360 degrees, so for a real lens this is the
    field of view its mask shows; it is bounded by the lens model's limit and by ``cam.fov``,
    and 0 for an empty mask.
    """
    height, width = mask.shape
    dtype = jnp.result_type(cam.fx)
    rows, cols = jnp.meshgrid(jnp.arange(height, dtype=dtype), jnp.arange(width, dtype=dtype),
                              indexing="ij")
    half_model = _HALF_ANGLE[type(cam)](cam)
    theta = _edge_half_angles(cam, jnp.stack([cols, rows], axis=-1), half_model)
    widest = jnp.max(jnp.where(jnp.asarray(mask) > 0, theta, 0.0))
    return 2.0 * jnp.minimum(widest, 0.5 * cam.fov)


def describe_field_of_view(cam) -> str:
    """One line for reports, in degrees: what the image sees, the model's limit, the fully held
    cone, and ``cam.fov`` where it is set below 360 (text from concrete values, not traced)."""
    fov = _field_of_view_jit(cam)
    deg = {k: math.degrees(float(getattr(fov, k))) for k in ("model", "inscribed", "effective")}
    cone = math.degrees(float(cam.fov))
    parts = [f"lens model limit {deg['model']:.1f} deg"]
    if cone < 360.0 - 1e-6:
        parts.append(f"cone {cone:.1f} deg")
    parts.append(f"full circle {deg['inscribed']:.1f} deg")
    return f"fov {deg['effective']:.1f} deg ({', '.join(parts)})"


__all__ = ["FieldOfView", "KB_BISECTIONS", "KB_GRID", "describe_field_of_view", "field_of_view",
           "mask_field_of_view", "model_limit"]
