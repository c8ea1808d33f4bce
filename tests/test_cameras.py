"""Camera models against closed forms, OpenCV, each other and finite differences."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from gijax.geometry import cameras as C
from gijax.geometry.rotations import axis_angle_to_matrix

W, H = 1224, 1028  # the paper's evaluation-board image size
_proj = jax.jit(C.project)
_unproj = jax.jit(C.unproject)
# Float32 round-trip bound (pixels): three float32 steps at coordinates in [1024, 2048), where one
# step is 1.22e-4. The coordinates themselves are float32, so below one step an error is 0.
# With alpha < 0.5 (DS, EUCM) the image corners lie close to the edge of the model's domain,
# where projection is ill-conditioned; there float32 reaches 5e-4 and the float32 property
# test draws alpha from the fisheye range [0.52, 0.8] (float64 covers the whole range).
F32_ROUND_TRIP = 3.7e-4
F64_ROUND_TRIP = 1e-8
# The Unified model (omni) with a small xi sees far past 90 degrees in the image corners (up to
# 127 degrees at xi = 0.6), where a pixel moves thousands of pixels per radian of the ray: the
# float32 rounding of the unprojected ray's direction, a few eps, then moves the pixel by
# eps * |d pixel / d ray| on top of the three steps above (8.5e-4 px measured at 7000 px/rad).
# Its bound is therefore per pixel: F32_ROUND_TRIP + F32_RAY_ROUNDINGS * eps * that
# sensitivity (the spectral norm of the projection's Jacobian with respect to the unit ray, in
# float64). Over 300 drawn lenses the largest excess was 0.90 eps * |J| (0.99 over 300 more
# under the suite's classic XLA emitters, at the pixels a lens determines: _check_round_trip).
F32_RAY_ROUNDINGS = 2.0
# The float32 round trip of the omni model is checked where its radial distortion's slope
# (d r_distorted / d r) is above this: nearer the fold a pixel hardly determines its angle.
OMNI_DETERMINED_SLOPE = 0.5


def ds_params(draw):
    return dict(fx=draw(st.floats(180, 320)), fy=draw(st.floats(180, 320)),
                cx=draw(st.floats(W / 2 - 30, W / 2 + 30)), cy=draw(st.floats(H / 2 - 30, H / 2 + 30)),
                xi=draw(st.floats(-0.4, 0.4)), alpha=draw(st.floats(0.35, 0.75)))


def eucm_params(draw):
    return dict(fx=draw(st.floats(180, 320)), fy=draw(st.floats(180, 320)),
                cx=draw(st.floats(W / 2 - 30, W / 2 + 30)), cy=draw(st.floats(H / 2 - 30, H / 2 + 30)),
                alpha=draw(st.floats(0.35, 0.75)), beta=draw(st.floats(0.6, 1.8)))


def kb_params(draw):
    return dict(fx=draw(st.floats(250, 350)), fy=draw(st.floats(250, 350)),
                cx=draw(st.floats(W / 2 - 30, W / 2 + 30)), cy=draw(st.floats(H / 2 - 30, H / 2 + 30)),
                k1=draw(st.floats(-0.05, 0.05)), k2=draw(st.floats(-0.01, 0.01)),
                k3=draw(st.floats(-0.005, 0.005)), k4=draw(st.floats(-0.001, 0.001)))


def eq_params(draw):
    return dict(fx=draw(st.floats(250, 350)), fy=draw(st.floats(250, 350)),
                cx=draw(st.floats(W / 2 - 30, W / 2 + 30)), cy=draw(st.floats(H / 2 - 30, H / 2 + 30)))


def omni_params(draw):
    # Kalibr omni + radtan calibrations of 180-200 degree lenses: xi about 0.6-1.8, a
    # negative k1, small k2 and tangential terms. The focal length puts the 195 degree circle
    # at a radius of 450-650 px, as such a lens is fitted to this sensor.
    xi, k1, k2 = draw(st.floats(0.6, 1.8)), draw(st.floats(-0.25, 0.05)), draw(st.floats(0.0, 0.06))
    rim = np.deg2rad(97.5)
    r = np.sin(rim) / (np.cos(rim) + xi)
    fx = draw(st.floats(450, 650)) / (r * (1.0 + k1 * r * r + k2 * r ** 4))
    return dict(fx=fx, fy=fx * draw(st.floats(0.99, 1.01)),
                cx=draw(st.floats(W / 2 - 30, W / 2 + 30)), cy=draw(st.floats(H / 2 - 30, H / 2 + 30)),
                xi=xi, k1=k1, k2=k2, p1=draw(st.floats(-1e-3, 1e-3)),
                p2=draw(st.floats(-1e-3, 1e-3)))


PARAM_STRATEGIES = {"ds": ds_params, "eucm": eucm_params, "kb": kb_params,
                    "equidistant": eq_params, "omni": omni_params}
FOV = {"ds": 360.0, "eucm": 360.0, "kb": 190.0, "equidistant": 195.0, "omni": 360.0}


@st.composite
def intrinsics(draw, model):
    return PARAM_STRATEGIES[model](draw)


def _pixels(dtype):
    """A grid over the whole image (every 7th pixel centre) plus random sub-pixel points."""
    g = np.asarray(C.pixel_grid(W, H))[::7, ::7].reshape(-1, 2)
    rng = np.random.default_rng(1)
    r = rng.uniform([-0.5, -0.5], [W - 0.5, H - 0.5], (4000, 2))
    return np.concatenate([g, r]).astype(dtype)


@jax.jit
def _round_trip(cam, px):
    ray, ok = C.unproject(cam, px)
    back, ok2 = C.project(cam, ray)
    return back, ok & ok2, ok, jnp.linalg.norm(ray, axis=-1)


def _omni_conditioning(params, px):
    """For the omni model at each pixel's float64 ray: ``|d pixel / d ray|`` (pixels per
    radian, the projection Jacobian's spectral norm), the slope of its radial distortion,
    ``1 + 3 k1 r^2 + 5 k2 r^4`` at the undistorted radius ``r``, and whether the pixel
    unprojects (the other two hold only there)."""
    with jax.enable_x64(True):
        cam = C.make_camera("omni", params, W, H, FOV["omni"], dtype=jnp.float64)
        ray, valid = C.unproject(cam, jnp.asarray(px, jnp.float64))
        jac = jax.vmap(jax.jacfwd(lambda r: C.project(cam, r)[0]))(ray)
        sensitivity = np.asarray(jnp.linalg.norm(jac, ord=2, axis=(-2, -1)))
    ray = np.asarray(ray)
    r2 = (ray[:, 0] ** 2 + ray[:, 1] ** 2) / (ray[:, 2] + params["xi"] * np.linalg.norm(
        ray, axis=-1)) ** 2
    slope = 1.0 + 3.0 * params["k1"] * r2 + 5.0 * params["k2"] * r2 * r2
    return sensitivity, slope, np.asarray(valid)


def _check_round_trip(model, params, dtype, tol):
    if dtype == jnp.float32 and "alpha" in params:
        params = dict(params, alpha=0.52 + 0.28 * (params["alpha"] - 0.35) / 0.4)
    if model == "kb":
        # The round trip is defined for lenses whose angle-to-radius polynomial rises over the
        # whole field of view, as calibrated lenses' does: where theta_d'(theta) nears 0 a pixel
        # no longer determines its angle (some draws even fold back inside 95 degrees).
        theta = np.linspace(0.0, np.radians(FOV[model]) / 2, 512)
        slope = 1 + sum((2 * i + 1) * params[f"k{i}"] * theta ** (2 * i) for i in range(1, 5))
        assume(slope.min() > 0.25)
    cam = C.make_camera(model, params, W, H, FOV[model], dtype=dtype)
    px = _pixels(np.dtype(dtype))
    back, ok, ok_un, norm = (np.asarray(a) for a in _round_trip(cam, jnp.asarray(px)))
    assert ok_un.sum() > 1000, "too few unprojectable pixels for a meaningful test"
    # Unprojectable pixels project back as valid, except on the rim of the DS / EUCM image
    # (r^2 -> 1 / (2 alpha - 1) in normalised units, beta r^2 for EUCM) where the angle is
    # ill-determined by the pixel and float32 rounding lands on either side of the boundary.
    lost = ok_un & ~ok
    if lost.any():
        assert model in ("ds", "eucm") and params["alpha"] > 0.5, (model, lost.sum())
        mx = (px[lost, 0] - params["cx"]) / params["fx"]
        my = (px[lost, 1] - params["cy"]) / params["fy"]
        r2 = (mx * mx + my * my) * params.get("beta", 1.0) * (2 * params["alpha"] - 1)
        assert r2.min() > 0.97, r2.min()
    err = np.abs(back.astype(np.float64) - px.astype(np.float64))[ok]
    if model == "omni" and dtype == jnp.float32:
        sensitivity, slope, _ = (a[ok] for a in _omni_conditioning(params, px))
        # As for Kannala-Brandt above: where the radial distortion's slope nears 0 (the fold
        # the domain stops at) a pixel no longer determines its angle, and the float32 round
        # trip there depends on how XLA orders the arithmetic: under the suite's classic
        # emitters 9.5 eps * |J| at a slope of 0.016, 2.35 at 0.30, at most 0.99 above 0.5
        # (300 drawn lenses). Those pixels are left to float64.
        determined = slope > OMNI_DETERMINED_SLOPE
        err = err[determined]
        tol = tol + F32_RAY_ROUNDINGS * np.finfo(np.float32).eps * sensitivity[determined, None]
    assert (err <= tol).all(), (model, params, err.max())
    np.testing.assert_allclose(norm[ok], 1.0, atol=1e-6 if dtype == jnp.float32 else 1e-14)
    return err.max()


@pytest.mark.parametrize("model", sorted(PARAM_STRATEGIES))
def test_round_trip_float32(model):
    @settings(max_examples=8, deadline=None)
    @given(intrinsics(model))
    def run(params):
        _check_round_trip(model, params, jnp.float32, F32_ROUND_TRIP)

    run()


def test_round_trip_omni_near_its_distortion_fold():
    """A lens whose radial distortion nearly folds inside the image (k1 = -0.125: slope 0.016 in
    a corner): the float32 round trip holds where the pixels determine their angle, and
    float64 holds everywhere, the fold's neighbourhood included."""
    params = dict(fx=413.5959509696173, fy=416.82716933656747, cx=582.0, cy=484.0, xi=0.75,
                  k1=-0.125, k2=0.0, p1=0.0, p2=0.0)
    _, slope, valid = _omni_conditioning(params, _pixels(np.float64))
    assert slope[valid].min() < 0.05 and (slope[valid] > OMNI_DETERMINED_SLOPE).mean() > 0.5
    _check_round_trip("omni", params, jnp.float32, F32_ROUND_TRIP)
    with jax.enable_x64(True):
        _check_round_trip("omni", params, jnp.float64, F64_ROUND_TRIP)


@pytest.mark.parametrize("model", sorted(PARAM_STRATEGIES))
def test_round_trip_float64(model):
    @settings(max_examples=5, deadline=None)
    @given(intrinsics(model))
    def run(params):
        with jax.enable_x64(True):
            _check_round_trip(model, params, jnp.float64, F64_ROUND_TRIP)

    run()


def test_round_trip_paper_ds_camera_float32():
    """The real calibration of REFERENCE section 3; pixel centres of the whole image."""
    params = dict(fx=232.0, fy=232.0, cx=611.5, cy=513.5, xi=-0.203, alpha=0.589)
    cam = C.make_camera("ds", params, W, H)
    px = C.pixel_grid(W, H)
    back, ok, _, _ = _round_trip(cam, px)
    err = np.abs(np.asarray(back, np.float64) - np.asarray(px, np.float64))[np.asarray(ok)]
    # At least a whole disc of radius 500 px is valid for this lens.
    assert np.asarray(ok).mean() > 0.7
    # 1.2207e-4 is one float32 step at coordinates >= 1024: the smallest nonzero error there.
    assert err.max() <= 1.2207032e-4
    assert np.mean(err > 1e-4) < 0.01


# ------------------------------------------------------------------ OpenCV oracle for KB


@settings(max_examples=8, deadline=None)
@given(intrinsics("kb"), st.integers(0, 2**31 - 1))
def test_kannala_brandt_matches_opencv(params, seed):
    rng = np.random.default_rng(seed)
    with jax.enable_x64(True):
        cam = C.make_camera("kb", params, W, H, 190.0, dtype=jnp.float64)
        k = np.array([[params["fx"], 0, params["cx"]], [0, params["fy"], params["cy"]], [0, 0, 1]])
        d = np.array([params[n] for n in ("k1", "k2", "k3", "k4")])
        # Points in front of the camera up to 75 degrees off axis (OpenCV divides by z).
        theta = rng.uniform(0, np.deg2rad(75), 300)
        phi = rng.uniform(-np.pi, np.pi, 300)
        dist = rng.uniform(0.5, 20, 300)
        pts = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                        np.cos(theta)], -1) * dist[:, None]
        ref, _ = cv2.fisheye.projectPoints(pts[:, None, :], np.zeros(3), np.zeros(3), k, d)
        ours, ok = _proj(cam, jnp.asarray(pts))
        inside = np.asarray(ok)
        assert inside.mean() > 0.5
        np.testing.assert_allclose(np.asarray(ours)[inside], ref[:, 0][inside], atol=1e-3)
        # Unprojection against cv2.fisheye.undistortPoints (normalised x/z, y/z), compared in
        # pixel units by scaling with the focal length.
        px = ref[:, 0][inside]
        und = cv2.fisheye.undistortPoints(px[:, None, :], k, d,
                                          criteria=(cv2.TERM_CRITERIA_COUNT
                                                    + cv2.TERM_CRITERIA_EPS, 50, 1e-14))[:, 0]
        ray, ok_u = _unproj(cam, jnp.asarray(px))
        ray = np.asarray(ray)
        assert np.asarray(ok_u).all()
        ours_n = ray[:, :2] / ray[:, 2:3]
        np.testing.assert_allclose(ours_n * [params["fx"], params["fy"]],
                                   und * [params["fx"], params["fy"]], atol=1e-3)


# ------------------------------------------------------------------ cross-model identities


def _sphere_points(n, seed):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True) * rng.uniform(0.3, 30, (n, 1))


@settings(max_examples=8, deadline=None)
@given(st.floats(0.3, 0.8), st.floats(150, 350), st.floats(150, 350))
def test_ds_xi0_equals_eucm_beta1(alpha, fx, fy):
    with jax.enable_x64(True):
        base = dict(fx=fx, fy=fy, cx=600.0, cy=500.0, alpha=alpha)
        ds = C.make_camera("ds", dict(base, xi=0.0), W, H, dtype=jnp.float64)
        eu = C.make_camera("eucm", dict(base, beta=1.0), W, H, dtype=jnp.float64)
        pts = jnp.asarray(_sphere_points(500, 3))
        pa, va = _proj(ds, pts)
        pb, vb = _proj(eu, pts)
        assert np.array_equal(np.asarray(va), np.asarray(vb))
        np.testing.assert_allclose(np.asarray(pa), np.asarray(pb), rtol=0, atol=1e-9)
        px = jnp.asarray(_pixels(np.float64)[:800])
        ra, ua = _unproj(ds, px)
        rb, ub = _unproj(eu, px)
        assert np.array_equal(np.asarray(ua), np.asarray(ub))
        np.testing.assert_allclose(np.asarray(ra)[np.asarray(ua)], np.asarray(rb)[np.asarray(ua)],
                                   atol=1e-12)


def test_equidistant_equals_kb_with_zero_k_and_closed_form():
    with jax.enable_x64(True):
        base = dict(fx=300.0, fy=290.0, cx=611.5, cy=513.5)
        eq = C.make_camera("equidistant", base, W, H, 195.0, dtype=jnp.float64)
        kb = C.make_camera("kb", dict(base, k1=0.0, k2=0.0, k3=0.0, k4=0.0), W, H, 195.0,
                           dtype=jnp.float64)
        pts = _sphere_points(800, 4)
        pa, va = _proj(eq, jnp.asarray(pts))
        pb, vb = _proj(kb, jnp.asarray(pts))
        assert np.array_equal(np.asarray(va), np.asarray(vb))
        np.testing.assert_allclose(np.asarray(pa), np.asarray(pb), atol=1e-9)
        # Closed form r = f * theta, checked on valid points.
        r = np.hypot(pts[:, 0], pts[:, 1])
        theta = np.arctan2(r, pts[:, 2])
        u = 300.0 * theta * pts[:, 0] / r + 611.5
        v = 290.0 * theta * pts[:, 1] / r + 513.5
        ok = np.asarray(va)
        in_view = (theta <= np.deg2rad(97.5)) & (u >= -0.5) & (u <= W - 0.5) & (v >= -0.5) & (
            v <= H - 0.5)
        assert np.array_equal(ok, in_view)
        np.testing.assert_allclose(np.asarray(pa)[ok], np.stack([u, v], -1)[ok], atol=1e-9)


def test_ds_closed_form_and_validity():
    """REFERENCE section 3 formulas in numpy, including the w2 validity bound."""
    xi, alpha, f, cx, cy = -0.203, 0.589, 232.0, 611.5, 513.5
    with jax.enable_x64(True):
        cam = C.make_camera("ds", dict(fx=f, fy=f, cx=cx, cy=cy, xi=xi, alpha=alpha), 5000, 5000,
                            dtype=jnp.float64)
        pts = _sphere_points(2000, 5)
        px, ok = _proj(cam, jnp.asarray(pts))
    x, y, z = pts.T
    d1 = np.linalg.norm(pts, axis=-1)
    d2 = np.sqrt(x * x + y * y + (xi * d1 + z) ** 2)
    den = alpha * d2 + (1 - alpha) * (xi * d1 + z)
    w1 = (1 - alpha) / alpha
    w2 = (w1 + xi) / np.sqrt(2 * w1 * xi + xi * xi + 1)
    valid = z > -w2 * d1
    u, v = f * x / den + cx, f * y / den + cy
    inside = (u >= -0.5) & (u <= 4999.5) & (v >= -0.5) & (v <= 4999.5)
    assert np.array_equal(np.asarray(ok), valid & inside)
    np.testing.assert_allclose(np.asarray(px)[valid], np.stack([u, v], -1)[valid], rtol=1e-11)


# ------------------------------------------------------------------ gradients


GRAD_CAMS = {
    "ds": dict(fx=232.0, fy=231.0, cx=611.5, cy=513.5, xi=-0.203, alpha=0.589),
    "eucm": dict(fx=232.0, fy=231.0, cx=611.5, cy=513.5, alpha=0.62, beta=1.1),
    "kb": dict(fx=300.0, fy=301.0, cx=611.5, cy=513.5, k1=0.01, k2=-0.004, k3=0.001,
               k4=-0.0002),
    "equidistant": dict(fx=300.0, fy=301.0, cx=611.5, cy=513.5),
    "omni": dict(fx=300.0, fy=301.0, cx=611.5, cy=513.5, xi=1.1, k1=-0.2, k2=0.04, p1=3e-4,
                 p2=-2e-4),
}


def _central_fd(f, x, h):
    g = np.zeros_like(x)
    for i in range(x.size):
        e = np.zeros_like(x)
        e.flat[i] = h
        g.flat[i] = (f(x + e) - f(x - e)) / (2 * h)
    return g


@pytest.mark.parametrize("model", sorted(GRAD_CAMS))
def test_gradients_match_central_differences(model):
    """d(weighted pixel sum)/d(points, every intrinsic, rig rotation and translation)."""
    rng = np.random.default_rng(7)
    with jax.enable_x64(True):
        names = C.CAMERA_MODELS[model].PARAMS
        theta0 = np.array([GRAD_CAMS[model][k] for k in names])
        # Rig pose of the camera: p_cam = R^T (p_rig - t), with R = R0 exp([w]x).
        r0 = np.asarray(axis_angle_to_matrix(jnp.array([0.1, -0.2, 0.05])))
        t0 = np.array([0.1, -0.05, 0.02])
        dirs = _sphere_points(40, 8)
        dirs = dirs[dirs[:, 2] > 0.2 * np.linalg.norm(dirs, axis=-1)]
        pts_rig = dirs @ r0.T + t0
        weights = rng.normal(size=(len(pts_rig), 2))

        def loss(theta, w, t, pts):
            cam = C.make_camera(model, dict(zip(names, theta)), W, H, dtype=jnp.float64)
            rot = jnp.asarray(r0) @ axis_angle_to_matrix(w)
            px, _ = C.project(cam, (pts - t) @ rot)
            return jnp.sum(px * weights)

        args = (jnp.asarray(theta0), jnp.zeros(3), jnp.asarray(t0), jnp.asarray(pts_rig))
        grads = jax.jit(jax.grad(loss, argnums=(0, 1, 2, 3)))(*args)
        lossj = jax.jit(loss)
        for k, (g, x) in enumerate(zip(grads, args)):
            x = np.asarray(x)

            def f(v, k=k):
                a = list(args)
                a[k] = jnp.asarray(v)
                return float(lossj(*a))

            h = 1e-6 * max(1.0, float(np.abs(x).max()))
            fd = _central_fd(f, x, h)
            scale = np.abs(fd).max()
            np.testing.assert_allclose(np.asarray(g), fd, rtol=1e-5, atol=1e-5 * scale,
                                       err_msg=f"{model}: argument {k}")


INVALID_POINTS = np.array([
    [0.0, 0.0, 0.0],  # the camera centre
    [0.0, 0.0, -1.0],  # straight behind, on the axis
    [1e-12, 0.0, -3.0],  # behind, just off the axis
    [0.3, -0.2, -1.0],  # behind
    [1.0, 0.0, -10.0],
    [5.0, 5.0, 1.0],  # in front but outside the image
    [1e5, -1e5, -1e5],
    [1.0, 0.0, 0.0],  # exactly 90 degrees
])


@pytest.mark.parametrize("model", sorted(GRAD_CAMS))
def test_invalid_points_finite_values_and_gradients(model):
    names = C.CAMERA_MODELS[model].PARAMS
    theta0 = jnp.array([GRAD_CAMS[model][k] for k in names], jnp.float32)

    def loss(theta, pts):
        cam = C.make_camera(model, dict(zip(names, theta)), 200, 200, 150.0)
        px, ok = C.project(cam, pts)
        ray, ok2 = C.unproject(cam, px * 3.0 - 250.0)  # mostly outside the model's image
        return jnp.sum(px) + jnp.sum(ray), (px, ok, ray, ok2)

    (val, (px, ok, ray, ok2)), grads = jax.jit(jax.value_and_grad(loss, argnums=(0, 1),
                                                                   has_aux=True))(
        theta0, jnp.asarray(INVALID_POINTS, jnp.float32))
    assert not np.asarray(ok).any()
    assert np.isfinite(float(val))
    assert np.all(np.isfinite(np.asarray(px))) and np.all(np.isfinite(np.asarray(ray)))
    for g in grads:
        assert np.all(np.isfinite(np.asarray(g))), (model, g)
    # Rays of invalid pixels are still unit vectors.
    np.testing.assert_allclose(np.linalg.norm(np.asarray(ray), axis=-1), 1.0, atol=1e-5)


def test_unproject_gradient_finite_everywhere_for_ds_outside_disc():
    cam = C.make_camera("ds", GRAD_CAMS["ds"], W, H)
    px = jnp.array([[-2000.0, 3000.0], [611.5, 513.5], [5000.0, 513.5]], jnp.float32)
    g = jax.jit(jax.grad(lambda p: jnp.sum(C.unproject(cam, p)[0])))(px)
    assert np.all(np.isfinite(np.asarray(g)))
    _, ok = _unproj(cam, px)
    assert np.asarray(ok).tolist() == [False, True, False]


# ------------------------------------------------------------------ jit / vmap / eager


def test_jit_vmap_eager_agree():
    pts = jnp.asarray(_sphere_points(64, 9), jnp.float32)
    for model, params in GRAD_CAMS.items():
        cams = [C.make_camera(model, {k: v * (1 + 0.01 * i) if k in ("fx", "fy") else v
                                      for k, v in params.items()}, W, H, 190.0) for i in range(3)]
        eager_px, eager_ok = C.project(cams[1], pts)  # not compiled as a whole
        jitted = [_proj(c, pts) for c in cams]
        stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *cams)
        vm_px, vm_ok = jax.jit(jax.vmap(C.project, in_axes=(0, None)))(stacked, pts)
        np.testing.assert_allclose(np.asarray(jitted[1][0]), np.asarray(eager_px), rtol=2e-6,
                                   atol=2e-4)
        assert np.array_equal(np.asarray(jitted[1][1]), np.asarray(eager_ok))
        assert np.asarray(eager_ok).sum() > 10
        for i in range(3):
            np.testing.assert_allclose(np.asarray(vm_px[i]), np.asarray(jitted[i][0]),
                                       rtol=2e-6, atol=2e-4)
            assert np.array_equal(np.asarray(vm_ok[i]), np.asarray(jitted[i][1]))
        # Batched over any leading shape: (4, 16, 3) gives the same as (64, 3).
        px4, _ = _proj(cams[0], pts.reshape(4, 16, 3))
        np.testing.assert_allclose(np.asarray(px4).reshape(64, 2), np.asarray(jitted[0][0]),
                                   rtol=1e-6, atol=1e-4)


def test_fov_limit_applies_to_every_model():
    # A point 80 degrees off axis is inside a 170 degree cone, outside a 150 degree one.
    a = np.deg2rad(80.0)
    p = jnp.array([[np.sin(a), 0.0, np.cos(a)]], jnp.float32)
    for model, params in GRAD_CAMS.items():
        wide = C.make_camera(model, params, W, H, 170.0)
        narrow = C.make_camera(model, params, W, H, 150.0)
        assert bool(_proj(wide, p)[1][0]) and not bool(_proj(narrow, p)[1][0]), model
        px, _ = _proj(wide, p)
        assert bool(_unproj(wide, px)[1][0]) and not bool(_unproj(narrow, px)[1][0])


def test_scale_camera_keeps_pixel_centre_convention():
    cam = C.make_camera("ds", GRAD_CAMS["ds"], W, H)
    half = C.scale_camera(cam, 0.5)
    assert (half.width, half.height) == (612, 514)
    pts = jnp.asarray(_sphere_points(50, 10), jnp.float32)
    a, oka = _proj(cam, pts)
    b, okb = _proj(half, pts)
    ok = np.asarray(oka & okb)
    # Pixel u covers [u - 0.5, u + 0.5]: edges (u + 0.5) scale by the factor.
    np.testing.assert_allclose((np.asarray(a)[ok] + 0.5) * 0.5 - 0.5, np.asarray(b)[ok],
                               atol=2e-4)


def test_camera_models_of_one_layout_have_distinct_tree_structures():
    """A Double Sphere and an EUCM camera have seven leaves each; their tree structures must
    still differ, or a jit cache may run one model's compiled program on the other (jaxlib's
    dataclass registration compares structures without their class). Leaves keep their names."""
    ds = C.make_camera("ds", dict(fx=1.0, fy=1.0, cx=5.0, cy=5.0, xi=0.0, alpha=0.3), 10, 10)
    eu = C.make_camera("eucm", dict(fx=1.0, fy=1.0, cx=5.0, cy=5.0, alpha=0.3, beta=1.0), 10, 10)
    assert jax.tree.structure(ds) != jax.tree.structure(eu)
    assert jax.tree.structure(ds) == jax.tree.structure(C.scale_camera(ds, 1.0))
    paths = [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_flatten_with_path(eu)[0]]
    assert paths == [".fx", ".fy", ".cx", ".cy", ".alpha", ".beta", ".fov"]
    back = jax.tree.unflatten(jax.tree.structure(eu), jax.tree.leaves(eu))
    assert type(back) is C.EUCM and (back.width, back.height) == (10, 10)
    proj = jax.jit(lambda cam: C.project(cam, jnp.array([0.0, 0.9, -0.2]))[0])
    np.testing.assert_allclose(proj(ds), C.project(ds, jnp.array([0.0, 0.9, -0.2]))[0])
    np.testing.assert_allclose(proj(eu), C.project(eu, jnp.array([0.0, 0.9, -0.2]))[0])
