"""Built-in layouts: positions, baselines, and occlusion masks against a numpy ray caster."""

import jax
import numpy as np
import pytest

from gijax.geometry.layouts import TRAIN_BASELINE, builtin_rig
from gijax.geometry.rig import pairwise_baselines, project_rig_points


def _numpy_cylinder_hit(origin, d, cx, cy, radius, z0, z1):
    """Independent capped-cylinder test: side wall by the quadratic, caps by the plane."""
    o = origin - np.array([cx, cy, 0.0])
    a = d[0] ** 2 + d[1] ** 2
    hits = []
    if a > 0:
        b = 2 * (o[0] * d[0] + o[1] * d[1])
        c = o[0] ** 2 + o[1] ** 2 - radius**2
        disc = b * b - 4 * a * c
        if disc >= 0:
            for t in ((-b - np.sqrt(disc)) / (2 * a), (-b + np.sqrt(disc)) / (2 * a)):
                if t >= 0 and z0 <= o[2] + t * d[2] <= z1:
                    hits.append(t)
    if d[2] != 0:
        for zc in (z0, z1):
            t = (zc - o[2]) / d[2]
            p = o + t * d
            if t >= 0 and p[0] ** 2 + p[1] ** 2 <= radius**2:
                hits.append(t)
    return bool(hits)


@pytest.fixture(scope="module")
def train_rig():
    return builtin_rig("paper-train")


def test_layout_geometry():
    train = builtin_rig("paper-train")
    b = pairwise_baselines(train)
    np.testing.assert_allclose(b[~np.eye(3, dtype=bool)], TRAIN_BASELINE, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(train.reference), np.asarray(train.translations[0]))
    t2, t3 = builtin_rig("paper-test2"), builtin_rig("paper-test3")
    np.testing.assert_allclose(pairwise_baselines(t2)[0, 1:], 1.0, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(t2.reference), np.asarray(t2.translations).mean(0),
                               atol=1e-7)
    b3 = pairwise_baselines(t3)
    assert t3.num_cameras == 4 and np.isclose(sorted(b3[0])[1], 1.0)


def test_occlusion_mask_matches_numpy_ray_caster(train_rig):
    occ = train_rig.occluder
    cyl = [float(v) for v in (occ.x, occ.y, occ.radius, occ.z_min, occ.z_max)]
    rng = np.random.default_rng(0)
    for i in range(train_rig.num_cameras):
        cam = train_rig.cameras[i]
        mask = np.asarray(train_rig.masks[i])
        centre = np.asarray(train_rig.translations[i], np.float64)
        # Pixels near the occluder's image and random pixels everywhere.
        blocked = np.argwhere(mask[1:-1, 1:-1] == 0) + 1
        inside_disc = np.argwhere(mask > 0)
        pick = np.concatenate([blocked[rng.choice(len(blocked), 60)],
                               inside_disc[rng.choice(len(inside_disc), 60)],
                               rng.integers(0, cam.height, (60, 2))])
        f, cx, cy = float(cam.fx), float(cam.cx), float(cam.cy)
        for row, col in pick:
            mx, my = (col - cx) / f, (row - cy) / f
            theta = np.hypot(mx, my)
            if abs(theta - np.deg2rad(97.5)) < 2e-3:
                continue  # exactly on the rim of the lens: either answer is right
            in_lens = theta <= np.deg2rad(97.5)
            d = np.array([np.sin(theta) * mx / max(theta, 1e-12),
                          np.sin(theta) * my / max(theta, 1e-12), np.cos(theta)])
            d = np.asarray(train_rig.rotations[i], np.float64) @ d
            expect = in_lens and not _numpy_cylinder_hit(centre, d, *cyl)
            assert bool(mask[row, col]) == expect, (i, row, col)
        # The occluder blocks a visible but small part of the lens disc (radius 510.5 px).
        disc = np.pi * 510.5**2
        blocked_frac = (disc - mask.sum()) / disc
        assert 0.001 < blocked_frac < 0.2, blocked_frac


def test_project_rig_points_respects_masks(train_rig):
    # A low point on the far side of the LiDAR from cam0 is hidden from cam0; a point high
    # above the rig is seen by every camera.
    occ = train_rig.occluder
    c0 = np.asarray(train_rig.translations[0])
    centre = np.array([float(occ.x), float(occ.y), 0.05])
    behind = centre + (centre - c0) * 2.0  # the far side of the cylinder from cam0
    above = np.array([0.0, 0.0, 5.0])
    px, ok = jax.jit(project_rig_points)(train_rig, np.array([behind, above], np.float32))
    ok = np.asarray(ok)
    assert not ok[0, 0]  # cam0 looks through the LiDAR
    assert ok[:, 1].all()  # everybody sees the sky point
