"""Lens draws: the drawn lenses end their field of view where the draw says, rise monotonically,
agree with OpenCV's fisheye model, and re-lensed rigs get masks of their own lenses."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from gijax.data.lens_draw import LENS_MODELS, LensDraw, draw_lens, lens_variant_rig, unit_radius
from gijax.geometry import cameras as cam_lib
from gijax.geometry.layouts import builtin_rig
from gijax.geometry.rig import scale_rig

BASE = cam_lib.make_camera("equidistant", dict(fx=80.0, fy=80.0, cx=127.5, cy=119.5), 256, 240)


def _ray(theta):
    return np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], -1)


def _radius(cam, theta):
    px, ok = cam_lib.project(cam, jnp.asarray(_ray(np.asarray(theta, np.float64)), jnp.float32))
    return np.hypot(px[..., 0] - cam.cx, px[..., 1] - cam.cy), np.asarray(ok)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), model=st.sampled_from(LENS_MODELS))
def test_field_of_view_ends_on_the_drawn_image_circle(seed, model):
    """The camera's own projection puts the field-of-view edge at the drawn circle (85-100 % of
    half the shorter side, here 120 px), the cone is 180-240 degrees, the principal point and
    size are kept."""
    cam = draw_lens(jax.random.PRNGKey(seed), BASE, model)
    fov = np.degrees(float(cam.fov))
    assert 180.0 - 1e-3 <= fov <= 240.0 + 1e-3
    r, ok = _radius(cam, 0.5 * float(cam.fov) - 1e-4)
    assert ok and 0.85 * 120 - 0.05 <= float(r) <= 120 + 0.05
    assert (cam.width, cam.height, float(cam.cx), float(cam.cy)) == (256, 240, 127.5, 119.5)
    assert type(cam).MODEL == model


@pytest.mark.parametrize("model,corner", [
    ("kb", dict(kb_k1=(-0.03, -0.03), kb_k2=(-0.003, -0.003))),
    ("kb", dict(kb_k1=(0.03, 0.03), kb_k2=(0.003, 0.003))),
    ("ds", dict(ds_xi=(-0.15, -0.15), ds_alpha=(0.6, 0.6))),
    ("ds", dict(ds_xi=(0.05, 0.05), ds_alpha=(0.5, 0.5))),
    ("equidistant", {})])
def test_corners_of_the_ranges_rise_monotonically_over_240_degrees(model, corner):
    """At the ends of every shape range and the widest field of view, the image radius grows
    strictly with the angle up to the edge, every ray there is valid, and unprojecting the
    pixels gives the rays back."""
    draw = LensDraw(fov_deg=(240.0, 240.0), **corner)
    cam = draw_lens(jax.random.PRNGKey(0), BASE, model, draw)
    theta = np.linspace(0.0, np.radians(119.9), 400)
    r, ok = _radius(cam, theta)
    assert ok.all()
    assert np.all(np.diff(r) > 0.05), np.diff(r).min()
    px, _ = cam_lib.project(cam, jnp.asarray(_ray(theta), jnp.float32))
    back, ok_back = cam_lib.unproject(cam, px)
    assert np.asarray(ok_back).all()
    np.testing.assert_allclose(np.asarray(back), _ray(theta), atol=2e-4)


def test_kannala_brandt_draw_matches_opencv_fisheye():
    """A drawn Kannala-Brandt lens projects like cv2.fisheye.projectPoints with the same
    intrinsics (OpenCV handles rays in front of the camera: theta < 90 degrees here)."""
    cam = draw_lens(jax.random.PRNGKey(7), BASE, "kb")
    rng = np.random.default_rng(0)
    theta = rng.uniform(0.0, np.radians(85.0), 200)
    phi = rng.uniform(-np.pi, np.pi, 200)
    pts = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    k = np.array([[float(cam.fx), 0, float(cam.cx)], [0, float(cam.fy), float(cam.cy)], [0, 0, 1]])
    d = np.array([float(cam.k1), float(cam.k2), float(cam.k3), float(cam.k4)])
    ref, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, d)
    got, ok = cam_lib.project(cam, jnp.asarray(pts, jnp.float32))
    assert np.asarray(ok).all()
    np.testing.assert_allclose(np.asarray(got), ref.reshape(-1, 2), atol=2e-3)


def test_unit_radius_is_each_model_at_unit_focal_length():
    """unit_radius against the closed forms: theta (equidistant), theta (1 + k1 theta^2 +
    k2 theta^4) (KB), and the Double Sphere radius of a unit ray."""
    th = np.linspace(0.01, 2.0, 7)
    np.testing.assert_allclose(unit_radius("equidistant", {}, th), th, rtol=1e-6)
    np.testing.assert_allclose(unit_radius("kb", dict(k1=0.02, k2=-0.001), th),
                               th * (1 + 0.02 * th**2 - 0.001 * th**4), rtol=1e-6)
    xi, a = -0.1, 0.55
    s, c = np.sin(th), np.cos(th)
    d2 = np.sqrt(s**2 + (xi + c) ** 2)
    np.testing.assert_allclose(unit_radius("ds", dict(xi=xi, alpha=a), jnp.asarray(th)),
                               s / (a * d2 + (1 - a) * (xi + c)), rtol=1e-5)


def test_draw_is_traceable_jit_equals_eager_and_vmap_equals_a_loop():
    keys = jax.random.split(jax.random.PRNGKey(3), 4)
    for model in LENS_MODELS:
        eager = [draw_lens(k, BASE, model) for k in keys]
        jitted = jax.jit(lambda k, m=model: draw_lens(k, BASE, m))(keys[0])
        mapped = jax.vmap(lambda k, m=model: draw_lens(k, BASE, m))(keys)
        for name in type(eager[0]).PARAMS + ("fov",):
            np.testing.assert_allclose(getattr(jitted, name), getattr(eager[0], name), rtol=1e-6)
            np.testing.assert_allclose(getattr(mapped, name),
                                       [getattr(e, name) for e in eager], rtol=1e-6)


def test_lens_variant_rig_keeps_poses_and_derives_masks_of_the_new_lenses():
    """One model for the rig ('random' draws it from the seed), each camera its own lens, poses
    unchanged; the body masks are derived again: pixels beyond the new image circle are 0,
    the centre is 1."""
    rig = scale_rig(builtin_rig("paper-train"), 1 / 8)
    out, model = lens_variant_rig(5, rig, "random")
    again, model2 = lens_variant_rig(5, rig, "random")
    assert model == model2 and model in LENS_MODELS
    assert all(type(c).MODEL == model for c in out.cameras)
    np.testing.assert_array_equal(out.rotations, rig.rotations)
    np.testing.assert_array_equal(out.translations, rig.translations)
    fovs = [float(c.fov) for c in out.cameras]
    assert len(set(fovs)) == 3                       # each camera draws its own lens
    for c, c2, m in zip(out.cameras, again.cameras, out.masks):
        assert float(c.fx) == float(c2.fx)
        m = np.asarray(m)
        assert m.shape == (c.height, c.width)
        assert m[0, 0] == 0 and m[c.height // 2, c.width // 2] == 1
        r, _ = _radius(c, 0.5 * float(c.fov) - 1e-4)
        yy, xx = np.mgrid[:c.height, :c.width]
        outside = np.hypot(xx - float(c.cx), yy - float(c.cy)) > float(r) + 1.0
        assert not m[outside].any()
    kb, name = lens_variant_rig(5, rig, "kb")
    assert name == "kb" and all(type(c).MODEL == "kb" for c in kb.cameras)


def test_bad_draws_are_refused_with_their_values():
    with pytest.raises(ValueError, match=r"fov_deg.*\(250.0, 200.0\)"):
        LensDraw(fov_deg=(250.0, 200.0))
    with pytest.raises(ValueError, match="circle"):
        LensDraw(circle=(0.0, 1.0))
    with pytest.raises(ValueError, match="'eucm' is not drawn"):
        draw_lens(jax.random.PRNGKey(0), BASE, "eucm")
    rig = builtin_rig("paper-train")
    with pytest.raises(ValueError, match="lens seed"):
        lens_variant_rig(-1, rig)
    with pytest.raises(ValueError, match="'pinhole'"):
        lens_variant_rig(0, rig, "pinhole")
