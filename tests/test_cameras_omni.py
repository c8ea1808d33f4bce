"""The Unified (Mei / Kalibr omni + radtan) camera model against OpenCV's cv2.omnidir, closed
forms and its Kalibr import.

OpenCV's reference pixels come from tests/fixtures/omnidir (opencv-contrib, which cannot be
installed beside gijax's OpenCV; the generator and its command are there).
"""

import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yaml

from gijax.geometry import cameras as C
from gijax.geometry.field_of_view import model_limit
from gijax.geometry.rig import project_rig_points
from gijax.io.rigfile import load_rig

FIXTURES = Path(__file__).parent / "fixtures" / "omnidir"
OPENCV = json.loads((FIXTURES / "omnidir_projections.json").read_text())
CASES = {c["name"]: c for c in OPENCV["cases"]}
WIDTH, HEIGHT = OPENCV["resolution"]
POINTS = np.asarray(OPENCV["points_m"])
# Measured: float64 agrees with OpenCV to 2.3e-13 px, float32 to 9.1e-5 px (below one float32
# step, 1.2e-4, at coordinates of 1024 and more).
F64_TOL, F32_TOL = 1e-9, 2.5e-4
_proj = jax.jit(C.project)
_unproj = jax.jit(C.unproject)


def _in_image(px):
    return ((px[:, 0] >= -0.5) & (px[:, 0] <= WIDTH - 0.5) & (px[:, 1] >= -0.5)
            & (px[:, 1] <= HEIGHT - 0.5))


@pytest.mark.parametrize("name", sorted(CASES))
def test_projection_matches_opencv_omnidir(name):
    case = CASES[name]
    ref = np.asarray(case["pixels"])
    for dtype, tol in ((jnp.float64, F64_TOL), (jnp.float32, F32_TOL)):
        with jax.enable_x64(dtype == jnp.float64):
            cam = C.make_camera("omni", case["params"], WIDTH, HEIGHT, dtype=dtype)
            px, ok = _proj(cam, jnp.asarray(POINTS, dtype))
        np.testing.assert_allclose(np.asarray(px, np.float64), ref, rtol=0, atol=tol,
                                   err_msg=f"{name}, {np.dtype(dtype).name}")
        # Every point lies inside the lens's domain: valid exactly where inside the image.
        assert np.array_equal(np.asarray(ok), _in_image(ref)), name


def test_opencv_omnidir_uses_integer_pixel_centres():
    """The fixture's own check: omnidir's undistortion map agrees with projectPoints at integer
    output pixels, far below the half pixel a pixel-corner convention would show."""
    assert all(c["pixel_centre_check_px"] < 1e-3 for c in OPENCV["cases"])


def test_unprojection_inverts_opencv_pixels():
    """OpenCV's pixels unproject to the directions of the points they came from."""
    with jax.enable_x64(True):
        for name, case in CASES.items():
            cam = C.make_camera("omni", case["params"], WIDTH, HEIGHT, dtype=jnp.float64)
            ref = np.asarray(case["pixels"])
            ray, ok = _unproj(cam, jnp.asarray(ref))
            inside = _in_image(ref)
            assert np.array_equal(np.asarray(ok), inside), name
            want = POINTS / np.linalg.norm(POINTS, axis=-1, keepdims=True)
            np.testing.assert_allclose(np.asarray(ray)[inside], want[inside], atol=1e-12,
                                       err_msg=name)


def test_xi_zero_without_distortion_is_a_pinhole():
    params = dict(fx=410.0, fy=405.0, cx=320.3, cy=239.6, xi=0.0, k1=0.0, k2=0.0, p1=0.0,
                  p2=0.0)
    with jax.enable_x64(True):
        cam = C.make_camera("omni", params, 640, 480, dtype=jnp.float64)
        rng = np.random.default_rng(3)
        pts = rng.normal(size=(200, 3)) * [1.0, 1.0, 1.0] + [0.0, 0.0, 0.3]
        px, ok = _proj(cam, jnp.asarray(pts))
        limit = float(model_limit(cam))
    x, y, z = pts.T
    u, v = 410.0 * x / z + 320.3, 405.0 * y / z + 239.6
    front = z > 0
    inside = front & (u >= -0.5) & (u <= 639.5) & (v >= -0.5) & (v <= 479.5)
    assert inside.sum() > 20 and (~front).sum() > 20
    assert np.array_equal(np.asarray(ok), inside)
    np.testing.assert_allclose(np.asarray(px)[front], np.stack([u, v], -1)[front], rtol=1e-12)
    # The limit of a pinhole: the forward hemisphere.
    np.testing.assert_allclose(limit, math.pi, rtol=1e-12)


def test_optical_axis_maps_to_principal_point():
    for case in CASES.values():
        p = case["params"]
        cam = C.make_camera("omni", p, WIDTH, HEIGHT)
        px, ok = _proj(cam, jnp.asarray([[0.0, 0.0, 2.5]]))
        assert bool(ok[0])
        np.testing.assert_array_equal(np.asarray(px[0]), np.float32([p["cx"], p["cy"]]))
        ray, ok = _unproj(cam, jnp.asarray([[p["cx"], p["cy"]]], jnp.float32))
        assert bool(ok[0])
        np.testing.assert_allclose(np.asarray(ray[0]), [0.0, 0.0, 1.0], atol=1e-7)


def _ray(theta, phi=0.3):
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                     np.cos(theta)], -1)


@pytest.mark.parametrize("xi,k1,k2", [(0.8, 0.0, 0.0), (1.0, 0.0, 0.0), (1.8, 0.0, 0.0),
                                      (0.9, -0.3, 0.0), (1.2, -0.4, 0.05), (1.5, 0.05, 0.02)])
def test_model_limit_closed_form_and_ray_sweep(xi, k1, k2):
    """The limit from the sphere (cos(theta) = -min(xi, 1 / xi)) or the radial fold (the first
    positive root of 1 + 3 k1 s + 5 k2 s^2, by numpy), against a bisection on project()."""
    with jax.enable_x64(True):
        cam = C.make_camera("omni", dict(fx=1.0, fy=1.0, cx=5e6, cy=5e6, xi=xi, k1=k1, k2=k2,
                                         p1=0.0, p2=0.0), 10 ** 7, 10 ** 7, dtype=jnp.float64)
        half = 0.5 * float(model_limit(cam))
        sphere = math.acos(-min(xi, 1.0 / xi))
        roots = [r.real for r in np.roots([5 * k2, 3 * k1, 1.0])
                 if abs(r.imag) < 1e-12 and r.real > 0]
        want = sphere
        if roots and (xi <= 1.0 or min(roots) < 1.0 / (xi * xi - 1.0)):
            # The angle of undistorted radius r: sin(t) / (cos(t) + xi) = r, on the rising
            # branch, by bisection.
            r = math.sqrt(min(roots))
            lo, hi = 0.0, sphere
            for _ in range(200):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if math.sin(mid) / (math.cos(mid) + xi) < r else (lo, mid)
            want = min(lo, sphere)
        np.testing.assert_allclose(half, want, atol=1e-9)
        valid = jax.jit(lambda c, p: C.project(c, p)[1])
        lo, hi = 0.0, math.pi
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if bool(valid(cam, jnp.asarray(_ray(mid)))) else (lo, mid)
        # project() also refuses a denominator below 1e-6 of the distance, just before a
        # limit where the radius diverges (xi <= 1 without a fold).
        assert 0.0 <= half - lo <= (5e-3 if xi <= 1.0 and not roots else 1e-9)


def test_unprojection_refuses_pixels_past_the_rim():
    """xi > 1: pixels outside the image circle have no direction; far-off pixels stay finite,
    with finite gradients."""
    p = CASES["xi1.8-radtan"]["params"]
    cam = C.make_camera("omni", p, WIDTH, HEIGHT)
    px = jnp.asarray([[p["cx"] + 300.0, p["cy"]], [p["cx"] + 600.0, p["cy"]], [-1e5, 3e5]],
                     jnp.float32)
    ray, ok = _unproj(cam, px)
    assert np.asarray(ok).tolist() == [True, False, False]
    g = jax.jit(jax.grad(lambda c, q: jnp.sum(C.unproject(c, q)[0]), argnums=(0, 1)))(cam, px)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree_util.tree_leaves(g))


# ------------------------------------------------------------------ Kalibr import


def test_kalibr_camchain_imports_and_projects_like_opencv():
    path = FIXTURES / "camchain_omni.yaml"
    chain = yaml.safe_load(path.read_text())
    rig = load_rig(path)
    assert [c.MODEL for c in rig.cameras] == ["omni", "omni"]
    assert [(c.width, c.height) for c in rig.cameras] == [(WIDTH, HEIGHT)] * 2
    # cam0 is the rig frame; cam1's points reach it through the inverse of T_cn_cnm1.
    t10 = np.asarray(chain["cam1"]["T_cn_cnm1"], np.float64)
    homog = np.concatenate([POINTS, np.ones((len(POINTS), 1))], -1)
    for i, (name, in_rig) in enumerate((("xi1.2-radtan", POINTS),
                                        ("xi1.8-radtan", (homog @ np.linalg.inv(t10).T)[:, :3]))):
        ref = np.asarray(CASES[name]["pixels"])
        px, ok = jax.jit(project_rig_points)(rig, jnp.asarray(in_rig, jnp.float32))
        inside = _in_image(ref)
        assert np.array_equal(np.asarray(ok[i]), inside)
        np.testing.assert_allclose(np.asarray(px[i], np.float64)[inside], ref[inside], atol=1e-3,
                                   err_msg=f"camera {i}")


def _chain(tmp_path, **cam0):
    chain = yaml.safe_load((FIXTURES / "camchain_omni.yaml").read_text())
    chain["cam0"].update(cam0)
    for k in [k for k, v in cam0.items() if v is None]:
        chain["cam0"].pop(k)
    path = tmp_path / "camchain.yaml"
    path.write_text(yaml.safe_dump(chain))
    return path


def test_kalibr_omni_without_distortion(tmp_path):
    rig = load_rig(_chain(tmp_path, distortion_model="none", distortion_coeffs=[]))
    p = C.camera_params(rig.cameras[0])
    assert (p["xi"], p["fx"], p["cy"]) == (np.float32(1.2), 500.0, np.float32(510.2))
    assert (p["k1"], p["k2"], p["p1"], p["p2"]) == (0.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize("fields,field", [
    (dict(distortion_model="equidistant"), "distortion_model"),
    (dict(distortion_model="fov", distortion_coeffs=[0.9]), "distortion_model"),
    (dict(distortion_coeffs=[-0.25, 0.06, 0.0]), "distortion_coeffs"),
    (dict(distortion_coeffs=None), "distortion_coeffs"),
    (dict(intrinsics=[500.0, 501.5, 641.0, 510.2]), "intrinsics"),
])
def test_kalibr_omni_refusals_name_file_camera_and_field(tmp_path, fields, field):
    path = _chain(tmp_path, **fields)
    with pytest.raises(ValueError) as exc:
        load_rig(path)
    msg = str(exc.value)
    assert "\n" not in msg
    assert str(path) in msg and "camera 'cam0'" in msg and f"field '{field}'" in msg
