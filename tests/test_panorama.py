"""Equirectangular panoramas: closed-form directions, the longitude direction against two
independent constructions (a camera looking out, the release's formula), and the pixel <->
direction round trip."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gijax.geometry.panorama import Panorama, direction_to_pixel, pixel_to_direction, ray_grid


@pytest.mark.parametrize("pano", [Panorama.hemisphere(16, 64), Panorama.sphere(20, 40)])
def test_ray_grid_matches_numpy_closed_form(pano):
    rays = np.asarray(ray_grid(pano))
    col = np.arange(pano.width) + 0.5
    row = np.arange(pano.height) + 0.5
    lon = -np.pi + 2 * np.pi * col / pano.width
    lat = pano.lat_min + (pano.lat_max - pano.lat_min) * row / pano.height
    theta = lat[:, None] + np.pi / 2  # polar angle from +z
    # Longitude grows towards -y (see the next two tests for why that is the common layout).
    ref = np.stack(np.broadcast_arrays(np.sin(theta) * np.cos(lon), -np.sin(theta) * np.sin(lon),
                                       np.cos(theta)), -1)
    np.testing.assert_allclose(rays, ref, atol=2e-6)
    # The hemisphere never looks below the rig plane; its first row is near the pole (+z).
    if pano.lat_max == 0.0:
        assert rays[..., 2].min() > 0 and rays[0, :, 2].min() > np.cos(np.pi / 2 / pano.height)


def test_known_directions():
    pano = Panorama.sphere(180, 360)
    px, ok = direction_to_pixel(pano, jnp.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0],
                                                 [0, 0, -1.0], [-1.0, -1e-7, 0]]))
    px = np.asarray(px)
    assert np.asarray(ok).all()
    np.testing.assert_allclose(px[0], [179.5, 89.5], atol=1e-4)  # lon 0 on the equator
    np.testing.assert_allclose(px[1], [269.5, 89.5], atol=1e-4)  # lon +90 is -y
    np.testing.assert_allclose(px[2, 1], -0.5, atol=1e-4)  # the pole, top edge
    np.testing.assert_allclose(px[3, 1], 179.5, atol=1e-4)  # the opposite pole, bottom edge
    np.testing.assert_allclose(px[4, 0], 359.5, atol=1e-3)  # lon just below +180: right edge
    _, ok = direction_to_pixel(Panorama.hemisphere(90, 360), jnp.array([[0.0, 0.3, -1.0]]))
    assert not bool(ok[0])


def test_longitude_grows_to_the_right_of_a_viewer_looking_out():
    """A pinhole camera at the centre looking at the horizon with the pole up (camera frame x
    right, y down, z forward, built here from the pole and the viewing direction alone): points
    to its right are further right in the panorama, points above it higher, and the image of a
    small cross is not mirrored."""
    pano = Panorama.sphere(90, 360)
    up = np.array([0.0, 0.0, 1.0])                       # the panorama pole, row 0
    for lon0 in np.radians([-150.0, -40.0, 0.0, 75.0, 160.0]):
        forward = np.array([np.cos(lon0), -np.sin(lon0), 0.0])
        # Orthonormal camera axes from the viewer's geometry, without the panorama module.
        down = -up
        right = np.cross(down, forward)                  # x = y cross z (right-handed camera)
        centre = forward
        to_right = forward + 0.1 * right
        above = forward - 0.1 * down
        px = np.asarray(direction_to_pixel(pano, jnp.asarray(np.stack([centre, to_right, above]),
                                                             jnp.float32))[0])
        dcol = (px[1, 0] - px[0, 0] + 180) % 360 - 180
        assert dcol > 4.0, (np.degrees(lon0), px)        # right in the world, right in the image
        assert abs(px[1, 1] - px[0, 1]) < 1e-3
        assert px[2, 1] < px[0, 1] - 2.0                 # up in the world, up in the image
        assert abs((px[2, 0] - px[0, 0] + 180) % 360 - 180) < 1e-3


def test_pixels_equal_the_release_equirectangular_formula():
    """The release's panorama: frame E with its pole on -y_E, longitude atan2(x_E, z_E) from
    -pi at column 0, latitude atan2(y_E, hypot(z_E, x_E)) from -pi/2 at row 0, pixel centres at
    i + 0.5. With z_G = -y_E, x_G = z_E, y_G = -x_E it is gijax's panorama pixel for pixel."""
    pano = Panorama.hemisphere(40, 160)
    rng = np.random.default_rng(3)
    d_e = rng.normal(size=(500, 3))
    d_e = d_e[d_e[:, 1] < -0.05]                         # the hemisphere around the pole -y_E
    u = (np.arctan2(d_e[:, 0], d_e[:, 2]) + np.pi) / (2 * np.pi) * pano.width - 0.5
    lat = np.arctan2(d_e[:, 1], np.hypot(d_e[:, 2], d_e[:, 0]))
    v = (lat + np.pi / 2) / (np.pi / 2) * pano.height - 0.5
    d_g = np.stack([d_e[:, 2], -d_e[:, 0], -d_e[:, 1]], -1)
    with jax.enable_x64(True):
        px, ok = direction_to_pixel(pano, jnp.asarray(d_g))
    assert np.asarray(ok).all()
    np.testing.assert_allclose(np.asarray(px), np.stack([u, v], -1), atol=1e-9)


@settings(max_examples=10, deadline=None)
@given(st.integers(4, 300), st.integers(4, 600), st.booleans(), st.integers(0, 2**31 - 1))
def test_pixel_direction_round_trip(h, w, sphere, seed):
    pano = Panorama.sphere(h, w) if sphere else Panorama.hemisphere(h, w)
    rng = np.random.default_rng(seed)
    # Away from the poles, where longitude is undefined.
    px = rng.uniform([-0.5, 0.0], [w - 0.5, h - 1.0], (200, 2))
    with jax.enable_x64(True):
        d = pixel_to_direction(pano, jnp.asarray(px))
        np.testing.assert_allclose(np.linalg.norm(np.asarray(d), axis=-1), 1.0, atol=1e-12)
        back, ok = direction_to_pixel(pano, d * 3.7)  # any length
    assert np.asarray(ok).all()
    err = np.asarray(back) - px
    err[:, 0] = (err[:, 0] + w / 2) % w - w / 2  # longitude wraps
    np.testing.assert_allclose(err, 0.0, atol=1e-8)
