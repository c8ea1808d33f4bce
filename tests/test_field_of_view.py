"""Field of view per camera model: closed forms against numeric searches on project()."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gijax.geometry.cameras import make_camera, project
from gijax.geometry.field_of_view import describe_field_of_view, field_of_view, model_limit

# Cameras on a huge image with the principal point in its middle: only the model's own domain
# limits project() along a ray sweep, never the image edge.
HUGE = 10 ** 7
CENTRE = dict(fx=1.0, fy=1.0, cx=HUGE / 2, cy=HUGE / 2)
# Compiled once per camera model and size: far cheaper than op-by-op dispatch.
FOV = jax.jit(field_of_view)
LIMIT = jax.jit(model_limit)
PAPER_DS = dict(fx=232.0, fy=232.0, cx=611.5, cy=513.5, xi=-0.203, alpha=0.589)

# project() also refuses a pixel whose denominator is below 1e-6 of the point's distance. Where
# the model's radius diverges at its limit (EUCM with alpha < 0.5, and alpha = 0.5 with xi = 0,
# whose limit is the backward axis), that guard stops the sweep a little earlier: GUARD_TOL.
GUARD_TOL = 5e-3
DS_CASES = [(-0.203, 0.589, 1e-9), (0.3, 0.7, 1e-9), (-0.3, 0.45, 1e-9), (0.5, 0.3, 1e-9),
            (0.1, 0.9, 1e-9), (0.0, 0.5, GUARD_TOL)]
EUCM_CASES = [(0.62, 1.1, 1e-9), (0.3, 0.8, GUARD_TOL), (0.5, 1.0, GUARD_TOL),
              (0.75, 2.0, 1e-9)]


def _ray(theta, phi):
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)


def _bisect(pred, lo, hi, steps=60):
    """The boundary of ``pred`` (true at ``lo``, false at ``hi``), elementwise."""
    lo, hi = np.array(lo, np.float64), np.array(hi, np.float64)
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        ok = np.asarray(pred(mid))
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    return lo


def _valid_until(cam, phi=0.3):
    """Largest angle to +z up to which project() accepts the ray, by bisection."""
    proj = jax.jit(lambda c, p: project(c, p)[1])
    return float(_bisect(lambda t: proj(cam, jnp.asarray(_ray(t, phi))), 0.0, math.pi))


def _basalt_ds_half_angle(xi, alpha):
    # Written as basalt's DoubleSphereCamera::project states its validity test.
    w1 = (1.0 - alpha) / alpha if alpha > 0.5 else alpha / (1.0 - alpha)
    w2 = (w1 + xi) / math.sqrt(2.0 * w1 * xi + xi * xi + 1.0)
    return math.acos(-w2)  # z > -w2 |p|  <=>  cos(theta) > -w2


@pytest.mark.parametrize("xi,alpha,tol", DS_CASES)
def test_double_sphere_limit(xi, alpha, tol):
    with jax.enable_x64(True):
        cam = make_camera("ds", dict(CENTRE, xi=xi, alpha=alpha), HUGE, HUGE, dtype=jnp.float64)
        limit = float(LIMIT(cam))
        np.testing.assert_allclose(limit, 2 * _basalt_ds_half_angle(xi, alpha), atol=1e-12)
        assert 0.0 <= limit - 2 * _valid_until(cam) <= tol
        # Within the limit the image radius grows with the angle (one pixel per direction).
        theta = np.linspace(0.0, 0.5 * limit - tol, 4001)[1:-1]
        px, ok = project(cam, jnp.asarray(_ray(theta, 0.0)))
        assert bool(np.all(ok))
        assert np.all(np.diff(np.asarray(px[:, 0]) - cam.cx) > 0)


def test_double_sphere_paper_calibration():
    cam = make_camera("ds", PAPER_DS, 1224, 1028)
    assert math.degrees(float(LIMIT(cam))) == pytest.approx(249.27, abs=0.01)


@pytest.mark.parametrize("alpha,beta,tol", EUCM_CASES)
def test_eucm_limit(alpha, beta, tol):
    with jax.enable_x64(True):
        cam = make_camera("eucm", dict(CENTRE, alpha=alpha, beta=beta), HUGE, HUGE,
                          dtype=jnp.float64)
        assert 0.0 <= float(LIMIT(cam)) - 2 * _valid_until(cam) <= tol


def test_eucm_equals_double_sphere_without_xi():
    with jax.enable_x64(True):
        for alpha in (0.3, 0.6):
            ds = make_camera("ds", dict(CENTRE, xi=0.0, alpha=alpha), HUGE, HUGE,
                             dtype=jnp.float64)
            eu = make_camera("eucm", dict(CENTRE, alpha=alpha, beta=1.0), HUGE, HUGE,
                             dtype=jnp.float64)
            np.testing.assert_allclose(float(LIMIT(ds)), float(LIMIT(eu)), atol=1e-9)


def test_kannala_brandt_limit_where_radius_stops_increasing():
    k = dict(k1=0.02, k2=-0.01, k3=0.0005, k4=-0.0001)
    with jax.enable_x64(True):
        # Principal point at the origin: u is then the radius itself, to full precision, for
        # rays at azimuth 0.
        cam = make_camera("kb", dict(fx=1.0, fy=1.0, cx=0.0, cy=0.0, **k), HUGE, HUGE,
                          dtype=jnp.float64)
        proj = jax.jit(lambda c, p: project(c, p)[0][..., 0])
        # Where r(theta + h) = r(theta - h) is the radius's maximum to O(h^2).
        h = 1e-5

        def rising(t):
            radius = lambda a: proj(cam, jnp.asarray(_ray(a, 0.0)))  # noqa: E731
            return radius(t + h) > radius(t - h)

        by_sweep = float(_bisect(rising, 0.1, math.pi - 1e-3))
        # The same angle from the derivative's roots: d theta_d / d theta is a quartic in
        # theta^2; its smallest positive real root.
        roots = np.roots([9 * k["k4"], 7 * k["k3"], 5 * k["k2"], 3 * k["k1"], 1.0])
        t2 = min(r.real for r in roots if abs(r.imag) < 1e-12 and r.real > 0)
        limit = float(LIMIT(cam))
        np.testing.assert_allclose(limit, 2 * math.sqrt(t2), atol=1e-10)
        np.testing.assert_allclose(limit, 2 * by_sweep, atol=1e-8)
        assert 0.5 * limit < math.pi
        # project() refuses the rays just past it.
        _, ok = project(cam, jnp.asarray(_ray(np.array([0.5 * limit - 1e-6, 0.5 * limit + 1e-6]),
                                              0.0)))
        assert ok.tolist() == [True, False]


def test_monotone_models_see_the_whole_sphere():
    kb = make_camera("kb", dict(CENTRE, k1=0.01, k2=0.0, k3=0.0, k4=0.0), HUGE, HUGE)
    eq = make_camera("equidistant", CENTRE, HUGE, HUGE)
    for cam in (kb, eq):
        np.testing.assert_allclose(float(LIMIT(cam)), 2 * math.pi, rtol=1e-6)
        assert _valid_until(cam) == pytest.approx(math.pi, abs=1e-6)


def _edge_reach(cam, phis):
    """Per azimuth, the angle to +z at which project() leaves the image or the model's domain."""
    proj = jax.jit(lambda c, p: project(c, p)[1])
    phis = np.asarray(phis, np.float64)
    return _bisect(lambda t: proj(cam, jnp.asarray(_ray(t, phis))), np.zeros_like(phis),
                   np.full_like(phis, math.pi))


def _sweep_azimuths(cam):
    """Many azimuths plus those of the image's corners and of the perpendiculars to its sides,
    where the reach is largest and smallest."""
    cx, cy, fx, fy = (float(getattr(cam, k)) for k in ("cx", "cy", "fx", "fy"))
    corners = [math.atan2((v - cy) / fy, (u - cx) / fx)
               for u in (-0.5, cam.width - 0.5) for v in (-0.5, cam.height - 0.5)]
    return np.concatenate([np.linspace(-math.pi, math.pi, 721), corners,
                           [0.0, 0.5 * math.pi, math.pi, -0.5 * math.pi]])


IMAGE_CASES = {
    # circular fisheye: the lens limit lies inside the image's corners
    "ds paper": ("ds", PAPER_DS, 1224, 1028),
    # the same lens on a cropping sensor: the corners bound it
    "ds cropped": ("ds", dict(PAPER_DS, fx=400.0, fy=390.0), 1224, 1028),
    "kb off-centre": ("kb", dict(fx=300.0, fy=301.0, cx=600.0, cy=500.0, k1=0.01, k2=-0.002,
                                 k3=0.0003, k4=-4e-5), 1280, 960),
    # Unified: a circular image (xi > 1), and one that the sensor crops (xi < 1)
    "omni circular": ("omni", dict(fx=700.0, fy=698.0, cx=637.5, cy=513.0, xi=1.8, k1=-0.12,
                                   k2=0.08, p1=0.0, p2=0.0), 1280, 1024),
    "omni cropped": ("omni", dict(fx=350.0, fy=349.0, cx=639.3, cy=511.8, xi=0.9, k1=-0.2,
                                  k2=0.03, p1=0.0, p2=0.0), 1280, 1024),
}


@pytest.mark.parametrize("case", sorted(IMAGE_CASES))
def test_image_bounds_against_ray_sweep(case):
    model, params, w, h = IMAGE_CASES[case]
    with jax.enable_x64(True):
        cam = make_camera(model, params, w, h, dtype=jnp.float64)
        fov = FOV(cam)
        reach = _edge_reach(cam, _sweep_azimuths(cam))
        np.testing.assert_allclose(float(fov.effective), 2 * reach.max(), atol=1e-8)
        np.testing.assert_allclose(float(fov.inscribed), 2 * reach.min(), atol=1e-8)
        assert float(fov.inscribed) <= float(fov.effective) <= float(fov.model) + 1e-12
    if case == "ds paper":
        assert float(fov.effective) == pytest.approx(float(fov.model), abs=1e-12)
    if case == "ds cropped":
        assert float(fov.effective) < float(fov.model) - 0.1


def test_equidistant_image_closed_form_and_cone():
    # r = f theta: the nearest side is 80 px = 0.8 rad away, the corners 1.2806 rad.
    params = dict(fx=100.0, fy=100.0, cx=99.5, cy=79.5)
    cam = make_camera("equidistant", params, 200, 160)
    fov = FOV(cam)
    np.testing.assert_allclose(float(fov.inscribed), 1.6, rtol=1e-6)
    np.testing.assert_allclose(float(fov.effective), 2 * math.hypot(1.0, 0.8), rtol=1e-6)
    np.testing.assert_allclose(float(fov.model), 2 * math.pi, rtol=1e-6)
    # A set cone below both bounds them; a principal point off the image holds no full cone.
    coned = FOV(make_camera("equidistant", params, 200, 160, fov_deg=60.0))
    np.testing.assert_allclose([float(coned.inscribed), float(coned.effective)],
                               [math.radians(60.0)] * 2, rtol=1e-6)
    off = FOV(make_camera("equidistant", dict(params, cx=-10.0), 200, 160))
    assert float(off.inscribed) == 0.0


def test_vmap_over_cameras_and_report():
    cams = [make_camera("ds", dict(PAPER_DS, xi=xi, alpha=a), 1224, 1028)
            for xi, a, _ in DS_CASES[:2]]
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *cams)
    batched = jax.jit(jax.vmap(field_of_view))(stacked)
    for i, cam in enumerate(cams):
        one = FOV(cam)
        for k in ("model", "inscribed", "effective"):
            np.testing.assert_allclose(float(getattr(batched, k)[i]), float(getattr(one, k)),
                                       rtol=1e-6)
    text = describe_field_of_view(cams[0])
    assert text.startswith("fov 249.3 deg (lens model limit 249.3 deg, full circle ")
