"""Fisheye camera models as immutable pytrees with pure projection functions.

Conventions (used everywhere in gijax):

* Camera frame: x right, y down, z forward (OpenCV). Units: metres.
* Pixel centres: the centre of the top-left pixel is at (u, v) = (0, 0); pixel (i, j) covers
  [i - 0.5, i + 0.5] x [j - 0.5, j + 0.5]. This is the convention of OpenCV, Kalibr and basalt,
  so calibrated intrinsics are used unchanged. An image of width W spans u in [-0.5, W - 0.5].
* ``fov`` is the full cone angle of the field of view in radians, measured from the optical
  axis (+z) in both directions: a point is inside when its angle to +z is at most ``fov / 2``.

Every model exposes ``project(cam, points) -> (pixels, valid)`` and
``unproject(cam, pixels) -> (unit rays, valid)``, batched over any leading shape. Points that
are behind the camera, outside the field of view, outside the model's valid domain or outside
the image come back with ``valid = False`` and *finite* pixels; every square root and division
is guarded (:mod:`gijax.numerics`) so that gradients stay finite too (no NaN leaking through
``jnp.where``). Everything here is traceable (jit, vmap, grad in the points, pixels and
intrinsics; model names and image sizes are static) except ``camera_params``, which returns
Python floats for printing and files.
"""

from __future__ import annotations

import dataclasses
from typing import Union

import jax
import jax.numpy as jnp
import numpy as np

from gijax.numerics import guard_floor, safe_div, safe_norm, safe_sqrt

Array = jax.Array

# Newton iterations for the Kannala-Brandt inverse; quadratic convergence makes 12 ample
# for any monotonic polynomial in float64, and the loop length is fixed so it is jit/grad-safe.
_KB_NEWTON_ITERS = 12
# Newton iterations for the radial-tangential inverse of the Unified model (2-D, from the
# distorted point). Against 40 steps in float64 over whole 1280 x 1024 images: 5 steps reach
# 1e-11 (ray components) on the test lenses, and a lens near a fold of its radial distortion
# (k1 = -0.35, k2 = 0.06: slope 1 + 3 k1 r^2 + 5 k2 r^4 down to 0.08 at the corners) needs 10;
# 12 leave margin. What remains is float rounding: see docs/geometry.md, Accuracy.
_UNIFIED_NEWTON_ITERS = 12


def _off_axis(r2: Array) -> Array:
    """Squared radii at which ``sqrt`` (and so ``theta / r``) is exact; below, the on-axis limit
    is used (the same threshold as :func:`gijax.numerics.safe_sqrt`)."""
    return r2 > guard_floor(r2)


def _blend(alpha: Array, d: Array, z: Array, a2_rest: Array) -> Array:
    """``alpha * d + (1 - alpha) * z`` for ``d = sqrt(rest + z^2) >= |z|``, well conditioned.

    Past 90 degrees ``z < 0`` and the two terms cancel, which costs float32 several ulps of
    pixel accuracy at the rim of a wide lens. There the product with the conjugate gives the
    same value without the cancellation:
    ``(alpha^2 rest + (2 alpha - 1) z^2) / (alpha d - (1 - alpha) z)``, with
    ``a2_rest = alpha^2 rest``. The conjugate is used only where its own terms do not cancel
    (``z < 0`` and ``alpha >= 0.5``); both branches are finite everywhere.
    """
    direct = alpha * d + (1.0 - alpha) * z
    conj_den = alpha * d - (1.0 - alpha) * z
    conj = safe_div(a2_rest + (2.0 * alpha - 1.0) * z * z, conj_den)
    return jnp.where((z < 0.0) & (alpha >= 0.5), conj, direct)


def _field_of_view_ok(cam, points: Array) -> Array:
    """Angle between the point and +z at most fov/2, without an arccos (valid past 180 deg)."""
    norm = safe_norm(points)
    return points[..., 2] >= jnp.cos(0.5 * cam.fov) * norm - 1e-12 * norm


def _in_image(cam, pixels: Array) -> Array:
    u, v = pixels[..., 0], pixels[..., 1]
    return (u >= -0.5) & (u <= cam.width - 0.5) & (v >= -0.5) & (v <= cam.height - 0.5)


def _normalised(pixels: Array, cam) -> tuple[Array, Array]:
    return (pixels[..., 0] - cam.cx) / cam.fx, (pixels[..., 1] - cam.cy) / cam.fy


def _to_pixels_ratio(cam, x: Array, y: Array, den: Array, scale: Array) -> tuple[Array, Array]:
    """Pixels of the normalised coordinates ``(x / den, y / den)`` and where they are finite.

    ``(f * x) / den`` rounds once less than ``f * (x / den)``: a float32 ulp saved at the rim.
    A denominator below ``1e-6`` of the point's ``scale`` (its distance) would put the pixel a
    million focal lengths out; such points are reported not ``ok`` and get the principal point,
    which keeps values and gradients bounded.
    """
    ok = den > 1e-6 * scale
    den = jnp.where(ok, den, 1.0)
    mx = jnp.where(ok, (cam.fx * x) / den, 0.0)
    my = jnp.where(ok, (cam.fy * y) / den, 0.0)
    return jnp.stack([mx + cam.cx, my + cam.cy], axis=-1), ok


def _to_pixels(cam, mx: Array, my: Array) -> Array:
    return jnp.stack([cam.fx * mx + cam.cx, cam.fy * my + cam.cy], axis=-1)


def _camera(cls=None, *, params: tuple[str, ...]):
    """Register a frozen dataclass as a pytree: intrinsics are leaves, the size is static.

    Registered as a custom node, not with ``jax.tree_util.register_dataclass``: jaxlib compares
    dataclass tree structures without their class, so a Double Sphere and an EUCM camera (seven
    leaves each, same size) had equal structures, and a jit cache could hand one model the
    other's compiled program whenever their hashes met in a bucket.
    """

    def wrap(cls):
        cls = dataclasses.dataclass(frozen=True)(cls)
        cls.PARAMS = params
        names = (*params, "fov")
        keys = tuple(jax.tree_util.GetAttrKey(n) for n in names)

        def flatten_with_keys(cam):
            leaves = tuple((k, getattr(cam, n)) for k, n in zip(keys, names))
            return leaves, (cam.width, cam.height)

        def flatten(cam):
            return tuple(getattr(cam, n) for n in names), (cam.width, cam.height)

        def unflatten(size, leaves):
            return cls(**dict(zip(names, leaves)), width=size[0], height=size[1])

        jax.tree_util.register_pytree_with_keys(cls, flatten_with_keys, unflatten, flatten)
        return cls

    return wrap


@_camera(params=("fx", "fy", "cx", "cy", "xi", "alpha"))
class DoubleSphere:
    """Double Sphere model (Usenko et al. 2018): intrinsics fx, fy, cx, cy, xi, alpha."""

    fx: Array
    fy: Array
    cx: Array
    cy: Array
    xi: Array
    alpha: Array
    fov: Array
    width: int
    height: int

    MODEL = "ds"

    def _project(self, p: Array) -> tuple[Array, Array]:
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        xi, alpha = self.xi, self.alpha
        r2 = x * x + y * y
        d1 = safe_sqrt(r2 + z * z)
        zs = xi * d1 + z
        d2 = safe_sqrt(r2 + zs * zs)
        den = _blend(alpha, d2, zs, alpha * alpha * r2)
        # alpha/(1-alpha) below 0.5, (1-alpha)/alpha above: one expression, no 0/0 branch.
        w1 = jnp.minimum(alpha, 1.0 - alpha) / jnp.maximum(alpha, 1.0 - alpha)
        w2 = (w1 + xi) / safe_sqrt(2.0 * w1 * xi + xi * xi + 1.0)
        pixels, ok = _to_pixels_ratio(self, x, y, den, d1)
        return pixels, (z > -w2 * d1) & ok

    def _unproject(self, px: Array) -> tuple[Array, Array]:
        mx, my = _normalised(px, self)
        xi, alpha = self.xi, self.alpha
        r2 = mx * mx + my * my
        disc = 1.0 - (2.0 * alpha - 1.0) * r2
        valid = disc >= 0.0
        mz = (1.0 - alpha * alpha * r2) / (alpha * safe_sqrt(disc) + 1.0 - alpha)
        inner = mz * mz + (1.0 - xi * xi) * r2
        valid &= inner >= 0.0
        factor = (mz * xi + safe_sqrt(inner)) / (mz * mz + r2)
        ray = jnp.stack([factor * mx, factor * my, factor * mz - xi], axis=-1)
        return ray, valid


@_camera(params=("fx", "fy", "cx", "cy", "alpha", "beta"))
class EUCM:
    """Extended Unified Camera Model (Khomutenko et al. 2016): fx, fy, cx, cy, alpha, beta."""

    fx: Array
    fy: Array
    cx: Array
    cy: Array
    alpha: Array
    beta: Array
    fov: Array
    width: int
    height: int

    MODEL = "eucm"

    def _project(self, p: Array) -> tuple[Array, Array]:
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        alpha, beta = self.alpha, self.beta
        br2 = beta * (x * x + y * y)
        rho = safe_sqrt(br2 + z * z)
        den = _blend(alpha, rho, z, alpha * alpha * br2)
        w = jnp.minimum(alpha, 1.0 - alpha) / jnp.maximum(alpha, 1.0 - alpha)
        pixels, ok = _to_pixels_ratio(self, x, y, den, rho)
        return pixels, (z > -w * rho) & ok

    def _unproject(self, px: Array) -> tuple[Array, Array]:
        mx, my = _normalised(px, self)
        alpha, beta = self.alpha, self.beta
        r2 = mx * mx + my * my
        disc = 1.0 - (2.0 * alpha - 1.0) * beta * r2
        valid = disc >= 0.0
        mz = (1.0 - beta * alpha * alpha * r2) / (alpha * safe_sqrt(disc) + 1.0 - alpha)
        return jnp.stack([mx, my, mz], axis=-1), valid


@_camera(params=("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"))
class KannalaBrandt:
    """Kannala-Brandt / OpenCV fisheye: r = theta (1 + k1 theta^2 + ... + k4 theta^8)."""

    fx: Array
    fy: Array
    cx: Array
    cy: Array
    k1: Array
    k2: Array
    k3: Array
    k4: Array
    fov: Array
    width: int
    height: int

    MODEL = "kb"

    def _distort(self, theta: Array) -> tuple[Array, Array]:
        """theta_d(theta) and its derivative."""
        t2 = theta * theta
        poly = 1.0 + t2 * (self.k1 + t2 * (self.k2 + t2 * (self.k3 + t2 * self.k4)))
        dpoly = 1.0 + t2 * (3 * self.k1 + t2 * (5 * self.k2 + t2 * (7 * self.k3 + t2 * 9 * self.k4)))
        return theta * poly, dpoly

    def _project(self, p: Array) -> tuple[Array, Array]:
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        r2 = x * x + y * y
        r = safe_sqrt(r2)
        theta = jnp.arctan2(r, z)
        theta_d, slope = self._distort(theta)
        off_axis = _off_axis(r2)
        # On the axis theta_d / r -> 1 / z (z > 0 there); both branches are finite.
        scale = jnp.where(off_axis, theta_d / r, safe_div(1.0, z))
        valid = (slope > 0.0) & (off_axis | (z > 0.0))
        return _to_pixels(self, scale * x, scale * y), valid

    def _unproject(self, px: Array) -> tuple[Array, Array]:
        mx, my = _normalised(px, self)
        r2 = mx * mx + my * my
        theta_d = safe_sqrt(r2)

        def newton(_, theta):
            f, df = self._distort(theta)
            return theta - (f - theta_d) / jnp.where(jnp.abs(df) > 1e-9, df, 1e-9)

        theta = jax.lax.fori_loop(0, _KB_NEWTON_ITERS, newton, theta_d)
        f, slope = self._distort(theta)
        # A root past pi (possible for a polynomial that turns back up) is not a direction.
        valid = ((slope > 0.0) & (jnp.abs(f - theta_d) < 1e-6 * (1.0 + theta_d)) & (theta >= 0.0)
                 & (theta <= jnp.pi))
        scale = jnp.where(_off_axis(r2), jnp.sin(theta) / theta_d, 1.0)
        return jnp.stack([scale * mx, scale * my, jnp.cos(theta)], axis=-1), valid


@_camera(params=("fx", "fy", "cx", "cy"))
class Equidistant:
    """Equidistant fisheye r = f * theta (the synthetic cameras of the paper's dataset)."""

    fx: Array
    fy: Array
    cx: Array
    cy: Array
    fov: Array
    width: int
    height: int

    MODEL = "equidistant"

    def _project(self, p: Array) -> tuple[Array, Array]:
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        r2 = x * x + y * y
        r = safe_sqrt(r2)
        theta = jnp.arctan2(r, z)
        off_axis = _off_axis(r2)
        scale = jnp.where(off_axis, theta / r, safe_div(1.0, z))
        valid = off_axis | (z > 0.0)
        return _to_pixels(self, scale * x, scale * y), valid

    def _unproject(self, px: Array) -> tuple[Array, Array]:
        mx, my = _normalised(px, self)
        r2 = mx * mx + my * my
        theta = safe_sqrt(r2)
        scale = jnp.where(_off_axis(r2), jnp.sin(theta) / theta, 1.0)
        ray = jnp.stack([scale * mx, scale * my, jnp.cos(theta)], axis=-1)
        return ray, theta <= jnp.pi


@_camera(params=("fx", "fy", "cx", "cy", "xi", "k1", "k2", "p1", "p2"))
class Unified:
    """Unified Camera Model (Mei and Rives 2007) with radial-tangential distortion: Kalibr's
    ``omni`` + ``radtan`` and OpenCV's ``cv2.omnidir`` (skew 0). Intrinsics fx, fy, cx, cy, xi,
    k1, k2, p1, p2.

    A point goes to the unit sphere, is projected from ``(0, 0, -xi)`` onto the normalised
    plane, ``(x, y) = (X, Y) / (Z + xi |P|)``, and is distorted there with
    ``r^2 = x^2 + y^2``::

        xd = x (1 + k1 r^2 + k2 r^4) + 2 p1 x y + p2 (r^2 + 2 x^2)
        yd = y (1 + k1 r^2 + k2 r^4) + p1 (r^2 + 2 y^2) + 2 p2 x y

    then ``(u, v) = (fx xd + cx, fy yd + cy)`` with the same integer pixel centres as every
    model here (OpenCV's and Kalibr's own convention, so calibrations are used unchanged).

    Domain: Kalibr's test ``Z > -w |P|`` with ``w = xi`` for ``xi <= 1`` and ``1 / xi``
    above, where the sphere's projection stops growing with the angle; and, as for
    Kannala-Brandt, the undistorted radius below the first fold of the radial distortion, where
    ``d(r (1 + k1 r^2 + k2 r^4)) / dr = 1 + 3 k1 r^2 + 5 k2 r^4`` first reaches 0 (closed form,
    :meth:`_before_fold`; the tangential terms are small in calibrated lenses and do not enter
    the domain). Unprojection inverts the distortion by :data:`_UNIFIED_NEWTON_ITERS` Newton
    steps (module constant, for its accuracy).
    """

    fx: Array
    fy: Array
    cx: Array
    cy: Array
    xi: Array
    k1: Array
    k2: Array
    p1: Array
    p2: Array
    fov: Array
    width: int
    height: int

    MODEL = "omni"

    def _fold_denominator(self) -> tuple[Array, Array]:
        """``(den, folds)``: the first positive root of ``1 + 3 k1 s + 5 k2 s^2`` (``s = r^2``)
        is ``2 / den`` where ``folds``; elsewhere the radius grows for every ``s >= 0``.

        The root is written as ``2 c / (-b + sqrt(b^2 - 4 a c))`` (``c = 1``), which covers
        ``k2 = 0`` (``s = -1 / (3 k1)`` for ``k1 < 0``) without a division by ``k2``.
        """
        b = 3.0 * self.k1
        disc = b * b - 20.0 * self.k2
        den = -b + safe_sqrt(disc)
        return den, (disc >= 0.0) & (den > 0.0)

    def _before_fold(self, r2: Array) -> Array:
        den, folds = self._fold_denominator()
        return ~folds | (r2 * den < 2.0)

    def _distort(self, x: Array, y: Array) -> tuple[Array, Array, tuple[Array, Array, Array]]:
        """The distorted point and the (symmetric) Jacobian ``(j11, j12, j22)`` of the map."""
        k1, k2, p1, p2 = self.k1, self.k2, self.p1, self.p2
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + k2 * r2)
        xy = x * y
        xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
        g = 2.0 * (k1 + 2.0 * k2 * r2)  # d radial / d r^2, doubled
        j11 = radial + g * x * x + 2.0 * p1 * y + 6.0 * p2 * x
        j12 = g * xy + 2.0 * p1 * x + 2.0 * p2 * y
        j22 = radial + g * y * y + 6.0 * p1 * y + 2.0 * p2 * x
        return xd, yd, (j11, j12, j22)

    def _newton_step(self, x, y, xd, yd):
        fx_, fy_, (j11, j12, j22) = self._distort(x, y)
        det = j11 * j22 - j12 * j12
        det = jnp.where(jnp.abs(det) > 1e-12, det, 1e-12)
        ex, ey = fx_ - xd, fy_ - yd
        return x - (j22 * ex - j12 * ey) / det, y - (j11 * ey - j12 * ex) / det

    def _undistort(self, xd: Array, yd: Array) -> tuple[Array, Array]:
        """The undistorted normalised point of ``(xd, yd)``.

        Newton's method from the distorted point, each iterate pulled back onto the disc where
        a solution can lie, so that far-off pixels stay finite: inside the radius where the
        radial distortion folds or, when it never does, within three times the distorted
        radius plus one (without a fold the radial factor stays above 4/9, so the solution
        lies well inside). The loop runs on constants and one last step carries the gradient:
        at a converged point that is the implicit one, ``J^-1`` times the residual's
        derivative, without differentiating the loop.
        """
        den, folds = self._fold_denominator()
        rd2 = xd * xd + yd * yd
        cap2 = jnp.where(folds, 2.0 / jnp.where(folds, den, 1.0),
                         (3.0 * safe_sqrt(rd2) + 1.0) ** 2)
        const, xd0, yd0, cap0 = jax.lax.stop_gradient((self, xd, yd, cap2))

        def inside(x, y):
            r2 = x * x + y * y
            shrink = jnp.where(r2 > cap0, safe_sqrt(cap0 / jnp.maximum(r2, cap0)), 1.0)
            return x * shrink, y * shrink

        def newton(_, xy):
            return inside(*const._newton_step(*xy, xd0, yd0))

        x, y = jax.lax.fori_loop(0, _UNIFIED_NEWTON_ITERS, newton, inside(xd0, yd0))
        return self._newton_step(x, y, xd, yd)

    def _project(self, p: Array) -> tuple[Array, Array]:
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        xi = self.xi
        rho2 = x * x + y * y
        d = safe_sqrt(rho2 + z * z)
        # z + xi d is (1 + xi) (alpha d + (1 - alpha) z) with alpha = xi / (1 + xi): the
        # blend of the Extended Unified model, whose conjugate form keeps float32 from
        # cancelling past 90 degrees when xi >= 1. (xi <= -1 sees nothing: z > |xi| d.)
        alpha = safe_div(xi, 1.0 + xi)
        den = (1.0 + xi) * _blend(alpha, d, z, alpha * alpha * rho2)
        # As in _to_pixels_ratio: a denominator below 1e-6 of the distance is a point a million
        # focal lengths out (xi < 1 near its limit); it gets the principal point, not valid.
        ok = den > 1e-6 * d
        den = jnp.where(ok, den, 1.0)
        mx = jnp.where(ok, x / den, 0.0)
        my = jnp.where(ok, y / den, 0.0)
        xd, yd, _ = self._distort(mx, my)
        w = jnp.minimum(xi, 1.0 / jnp.maximum(xi, 1.0))
        valid = ok & (z > -w * d) & self._before_fold(mx * mx + my * my)
        return _to_pixels(self, xd, yd), valid

    def _unproject(self, px: Array) -> tuple[Array, Array]:
        xd, yd = _normalised(px, self)
        x, y = self._undistort(xd, yd)
        back_x, back_y, _ = self._distort(x, y)
        residual = jnp.maximum(jnp.abs(back_x - xd), jnp.abs(back_y - yd))
        r2 = x * x + y * y
        xi = self.xi
        # The unit-sphere point on the line from (0, 0, -xi) through (x, y, 1): the root
        # nearer the optical axis; none past the sphere's rim (xi > 1, r^2 > 1 / (xi^2 - 1)).
        lift = 1.0 + (1.0 - xi * xi) * r2
        factor = (xi + safe_sqrt(lift)) / (1.0 + r2)
        ray = jnp.stack([factor * x, factor * y, factor - xi], axis=-1)
        # Converged: within float32 rounding of the distortion (the tolerance of the KB
        # inverse), or far inside float64's; a pixel the solve has not pinned down to that is
        # refused rather than returned up to f * 1e-6 px off in float64.
        tol = 1e-6 if jnp.finfo(residual.dtype).eps > 1e-10 else 1e-12
        valid = ((lift >= 0.0) & self._before_fold(r2)
                 & (residual <= tol * (1.0 + safe_sqrt(xd * xd + yd * yd))))
        return ray, valid


Camera = Union[DoubleSphere, EUCM, KannalaBrandt, Equidistant, Unified]
CAMERA_MODELS: dict[str, type] = {
    cls.MODEL: cls for cls in (DoubleSphere, EUCM, KannalaBrandt, Equidistant, Unified)
}


def project(cam: Camera, points: Array) -> tuple[Array, Array]:
    """Project camera-frame points ``(..., 3)`` to pixels ``(..., 2)`` and a validity mask.

    Valid means: inside the model's domain, inside the field of view and inside the image.
    Invalid points still get finite pixels (and finite gradients).
    """
    points = jnp.asarray(points)
    pixels, valid = cam._project(points)
    pixels = jnp.where(jnp.isfinite(pixels), pixels, 0.0)
    # The camera centre itself has no direction.
    sq = jnp.sum(points * points, axis=-1)
    nonzero = sq > guard_floor(sq)
    valid = valid & nonzero & _field_of_view_ok(cam, points) & _in_image(cam, pixels)
    return pixels, valid


def unproject(cam: Camera, pixels: Array) -> tuple[Array, Array]:
    """Unproject pixels ``(..., 2)`` to unit rays ``(..., 3)`` in the camera frame, and validity."""
    pixels = jnp.asarray(pixels)
    ray, valid = cam._unproject(pixels)
    ray = ray / safe_norm(ray, keepdims=True)
    fallback = jnp.zeros_like(ray).at[..., 2].set(1.0)
    finite = jnp.all(jnp.isfinite(ray), axis=-1)
    ray = jnp.where(finite[..., None], ray, fallback)
    valid = valid & finite & _field_of_view_ok(cam, ray) & _in_image(cam, pixels)
    return ray, valid


def make_camera(model: str, params: dict, width: int, height: int, fov_deg: float | None = None,
                dtype=jnp.float32) -> Camera:
    """Build a camera from a model name (``ds``, ``eucm``, ``kb``, ``equidistant``, ``omni``)
    and values.

    ``fov_deg`` defaults to the model's natural limit: 360 (no limit beyond the model's own
    domain) for all models.
    """
    if model not in CAMERA_MODELS:
        raise ValueError(f"unknown camera model {model!r}; expected one of {sorted(CAMERA_MODELS)}")
    cls = CAMERA_MODELS[model]
    missing = [k for k in cls.PARAMS if k not in params]
    if missing:
        raise ValueError(f"camera model {model!r} is missing intrinsics {missing}")
    # Degrees to radians in float64 first, so a value written as degrees reads back bit-exact.
    fov = jnp.asarray(np.deg2rad(np.float64(360.0 if fov_deg is None else fov_deg)), dtype)
    leaves = {k: jnp.asarray(params[k], dtype) for k in cls.PARAMS}
    return cls(**leaves, fov=fov, width=int(width), height=int(height))


def camera_params(cam: Camera) -> dict[str, float]:
    """The intrinsics as plain floats (for printing and files)."""
    return {k: float(getattr(cam, k)) for k in cam.PARAMS}


def scale_camera(cam: Camera, factor: float) -> Camera:
    """The same lens on an image resized by ``factor`` (pixel-centre convention preserved).

    A pixel centre u maps to (u + 0.5) * factor - 0.5, so cx, cy shift accordingly.
    """
    width = int(round(cam.width * factor))
    height = int(round(cam.height * factor))
    fx = cam.fx * width / cam.width
    fy = cam.fy * height / cam.height
    cx = (cam.cx + 0.5) * width / cam.width - 0.5
    cy = (cam.cy + 0.5) * height / cam.height - 0.5
    return dataclasses.replace(cam, fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height)


def pixel_grid(width: int, height: int, dtype=jnp.float32) -> Array:
    """(height, width, 2) pixel-centre coordinates (u, v) of an image."""
    u = jnp.arange(width, dtype=dtype)
    v = jnp.arange(height, dtype=dtype)
    uu, vv = jnp.meshgrid(u, v, indexing="xy")
    return jnp.stack([uu, vv], axis=-1)
