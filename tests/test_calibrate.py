"""Calibration refinement from unlabeled images.

The scenes are closed forms, independent of the renderer and of the refinement's own
projection: a textured sphere around the rig's reference point, each camera's image computed
in NumPy float64 from the equidistant lens (r = f theta), a ray-sphere intersection and a sum
of sinusoids of the hit direction. The true inverse distance of every panorama ray is then
known in closed form, and serves as the starting distance maps (the classical baseline's start
is exercised by the experiment and the command line).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gijax.calibrate import refine as ref
from gijax.geometry.cameras import make_camera
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import make_rig
from gijax.geometry.rotations import axis_angle_to_matrix

SIZE = 40
FOCAL = (SIZE / 2.0) / math.radians(97.5)
PANO_HW = (10, 40)
RADII = (1.6, 2.4)          # one sphere per frame, metres around the reference point


def _dtype():
    return jnp.float64 if jax.config.read("jax_enable_x64") else jnp.float32


def lens(fov_deg=195.0):
    c = (SIZE - 1) / 2.0
    return make_camera("equidistant", dict(fx=FOCAL, fy=FOCAL, cx=c, cy=c), SIZE, SIZE, fov_deg,
                       dtype=_dtype())


def triangle_rig(rotations=None, translations=None, fov_deg=195.0):
    side = 0.4
    ang = np.deg2rad([90.0, 210.0, 330.0])
    t = np.stack([side / math.sqrt(3) * np.cos(ang), side / math.sqrt(3) * np.sin(ang),
                  np.zeros(3)], -1) if translations is None else translations
    r = np.tile(np.eye(3), (3, 1, 1)) if rotations is None else rotations
    return make_rig([lens(fov_deg) for _ in range(3)], r, t, reference=np.zeros(3),
                    dtype=_dtype())


def texture(d, frame):
    """Three colour channels from sinusoids of the unit direction ``d`` (..., 3)."""
    rng = np.random.default_rng(10 + frame)
    out = []
    for _ in range(3):
        acc = 0.5 * np.ones(d.shape[:-1])
        for _ in range(3):
            k = rng.normal(size=3)
            k *= rng.uniform(4.0, 7.0) / np.linalg.norm(k)
            acc += 0.12 * np.sin(d @ k + rng.uniform(0, 2 * np.pi))
        out.append(acc)
    return np.clip(np.stack(out, -1), 0.0, 1.0)


def sphere_images(rig, radius, frame):
    """(N, SIZE, SIZE, 3) images of the sphere of ``radius`` around the origin, and masks."""
    v, u = np.meshgrid(np.arange(SIZE, dtype=np.float64), np.arange(SIZE, dtype=np.float64),
                       indexing="ij")
    c = (SIZE - 1) / 2.0
    mx, my = (u - c) / FOCAL, (v - c) / FOCAL
    theta = np.hypot(mx, my)
    s = np.where(theta > 0, np.sin(theta) / np.maximum(theta, 1e-12), 1.0)
    ray_c = np.stack([s * mx, s * my, np.cos(theta)], -1)
    inside = theta <= math.radians(97.5)
    images, masks = [], []
    for i in range(rig.num_cameras):
        rot = np.asarray(rig.rotations[i], np.float64)
        o = np.asarray(rig.translations[i], np.float64)
        d = ray_c @ rot.T
        b = d @ o
        t = -b + np.sqrt(b * b - (o @ o - radius**2))
        hit = o + t[..., None] * d
        img = texture(hit / radius, frame)
        images.append(np.where(inside[..., None], img, 0.0))
        masks.append(inside.astype(np.float64))
    return np.stack(images), np.stack(masks)


def frames(rig):
    ims, ms = zip(*(sphere_images(rig, r, f) for f, r in enumerate(RADII)))
    return np.stack(ims).astype(np.float32), np.stack(ms).astype(np.float32)


def turn(rig, cam, axis, degrees, shift=(0.0, 0.0, 0.0)):
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    rots = np.asarray(rig.rotations, np.float64).copy()
    trans = np.asarray(rig.translations, np.float64).copy()
    rots[cam] = rots[cam] @ np.asarray(axis_angle_to_matrix(jnp.asarray(
        axis * math.radians(degrees))))
    trans[cam] += shift
    return rig.replace(rotations=jnp.asarray(rots, _dtype()),
                       translations=jnp.asarray(trans, _dtype()))


def true_inverse_distance(n_frames=len(RADII)):
    # The reference point is the spheres' centre: every ray reads 1 / radius.
    return np.stack([np.full(PANO_HW, 1.0 / r) for r in RADII[:n_frames]])


def test_a_perturbed_camera_is_recovered():
    """Camera 2 turned by 2 degrees and moved by 15 mm; 90 steps bring it back within
    0.25 degrees (the start is 8 times that) and its position within half the start."""
    truth = triangle_rig()
    images, masks = frames(truth)
    start = turn(truth, 2, (0.3, -1.0, 0.4), 2.0, (0.0, 0.012, -0.009))
    before = ref.gauge_aligned_errors(start, truth)
    assert before["rotation_deg"][2] == pytest.approx(2.0, abs=1e-4)
    config = ref.RefineConfig(steps=90, blur=(1.5, 0.7), pano_hw=PANO_HW, lr_rotation=2e-3,
                              lr_translation=1e-3, lr_depth=0.01, min_texture=0.01)
    result = ref.refine_rig(start, images, masks, config, initial_inv=true_inverse_distance(),
                            progress=False)
    after = ref.gauge_aligned_errors(result.rig, truth)
    assert after["rotation_deg"][2] < 0.25, after
    assert after["rotation_deg"][1] < 0.25, after
    assert after["translation_mm"][2] < 0.5 * before["translation_mm"][2], (before, after)
    assert result.loss_after < 0.7 * result.loss_before
    # The gauge: camera 0 exactly as given, the camera 0-1 distance as given.
    np.testing.assert_array_equal(np.asarray(result.rig.rotations[0]),
                                  np.asarray(start.rotations[0]))
    np.testing.assert_array_equal(np.asarray(result.rig.translations[0]),
                                  np.asarray(start.translations[0]))
    d = lambda r: np.linalg.norm(np.asarray(r.translations[1], np.float64)  # noqa: E731
                                 - np.asarray(r.translations[0], np.float64))
    assert d(result.rig) == pytest.approx(d(start), rel=1e-6)
    assert result.moved["rotation_deg"][0] == 0.0
    assert result.moved["translation_mm"][0] == 0.0


def test_a_second_round_is_a_fresh_run_from_the_baselines_distances_at_the_refined_rig(
        monkeypatch):
    """``rounds=2`` is two one-round refinements in a row: the second starts from the rig the
    first reached, at the classical baseline's distances matched there (a stand-in here, so
    that no matcher compiles), with a fresh optimiser; the history runs on across both, the
    losses span both, and ``moved`` is measured from the rig given."""
    truth = triangle_rig()
    images, masks = frames(truth)
    start = turn(truth, 2, (0.3, -1.0, 0.4), 2.0, (0.0, 0.012, -0.009))
    calls = []

    def baseline_stand_in(rig, image, mask, pano):
        calls.append(rig)
        return np.full(pano.shape, 1.0 / RADII[(len(calls) - 1) % len(RADII)])

    monkeypatch.setattr(ref, "initial_inverse_distance", baseline_stand_in)
    config = ref.RefineConfig(steps=6, blur=(1.5, 0.7), pano_hw=PANO_HW, lr_rotation=2e-3,
                              lr_translation=1e-3, lr_depth=0.01, min_texture=0.01)
    first = ref.refine_rig(start, images, masks, config, initial_inv=true_inverse_distance(),
                           progress=False)
    assert calls == []
    second = ref.refine_rig(first.rig, images, masks, config, progress=False)
    assert len(calls) == len(RADII)
    calls.clear()
    both = ref.refine_rig(start, images, masks, config.replace(rounds=2),
                          initial_inv=true_inverse_distance(), progress=False)
    assert len(calls) == len(RADII)
    np.testing.assert_array_equal(np.asarray(both.rig.rotations), np.asarray(second.rig.rotations))
    np.testing.assert_array_equal(np.asarray(both.rig.translations),
                                  np.asarray(second.rig.translations))
    assert [h["step"] for h in both.history] == list(range(12))
    assert [h["round"] for h in both.history] == [0] * 6 + [1] * 6
    assert [h["loss"] for h in both.history] == [h["loss"] for h in first.history
                                                 + second.history]
    assert both.loss_before == first.loss_before and both.loss_after == second.loss_after
    assert both.initial is start
    expected = ref.pose_change(start, second.rig)
    np.testing.assert_allclose(both.moved["rotation_deg"], expected["rotation_deg"])
    np.testing.assert_allclose(both.moved["translation_mm"], expected["translation_mm"])
    # How far the second round moved each camera from the first round's calibration.
    assert first.round_moves == [] and len(both.round_moves) == 1
    between = ref.pose_change(first.rig, second.rig)
    np.testing.assert_allclose(both.round_moves[0]["rotation_deg"], between["rotation_deg"])
    np.testing.assert_allclose(both.round_moves[0]["translation_mm"], between["translation_mm"])
    assert max(between["rotation_deg"]) > 0.0
    with pytest.raises(ValueError, match=r"RefineConfig\.rounds must be an integer >= 1; "
                                         r"found 0"):
        config.replace(rounds=0)


def test_gauge_of_apply_calibration():
    """Any update leaves camera 0 and the 0-1 distance unchanged, and moves the others."""
    with jax.enable_x64(True):
        rig = triangle_rig()
        rng = np.random.default_rng(3)
        params = ref.initial_parameters(rig, np.zeros((1, *PANO_HW)), intrinsics=True)
        params = {k: jnp.asarray(rng.normal(size=v.shape) * 0.05) for k, v in params.items()}
        out = ref.apply_calibration(rig, params)
        np.testing.assert_array_equal(np.asarray(out.rotations[0]), np.asarray(rig.rotations[0]))
        np.testing.assert_array_equal(np.asarray(out.translations[0]),
                                      np.asarray(rig.translations[0]))
        t = np.asarray(out.translations) - np.asarray(out.translations[0])
        t0 = np.asarray(rig.translations) - np.asarray(rig.translations[0])
        assert np.linalg.norm(t[1]) == pytest.approx(np.linalg.norm(t0[1]), rel=1e-12)
        # Camera 2: translation added, rotation right-multiplied by the rotation vector's matrix.
        np.testing.assert_allclose(np.asarray(out.translations[2]),
                                   np.asarray(rig.translations[2]) + params["translation"][1],
                                   rtol=0, atol=1e-15)
        w = np.asarray(params["rotation"][1])
        angle = np.linalg.norm(w)
        k = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) / angle
        rodrigues = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k
        np.testing.assert_allclose(np.asarray(out.rotations[2]), rodrigues, atol=1e-14)
        assert float(out.cameras[1].fx) == pytest.approx(FOCAL * math.exp(params["focal"][1]),
                                                         rel=1e-12)
        # The gauge-aligned error of a rig against itself moved rigidly and scaled is zero.
        g = np.asarray(axis_angle_to_matrix(jnp.asarray([0.1, -0.2, 0.3])))
        moved = rig.replace(rotations=jnp.einsum("ij,njk->nik", g, rig.rotations),
                            translations=1.3 * rig.translations @ g.T + 0.5)
        err = ref.gauge_aligned_errors(moved, rig)
        np.testing.assert_allclose(err["rotation_deg"], 0.0, atol=1e-5)
        np.testing.assert_allclose(err["translation_mm"], 0.0, atol=1e-9)
        # ... because aligning the gauge undoes the motion and the scale exactly.
        aligned, scale = ref.align_gauge(moved, rig)
        assert scale == pytest.approx(1 / 1.3, rel=1e-12)
        np.testing.assert_allclose(np.asarray(aligned.rotations), np.asarray(rig.rotations),
                                   atol=1e-12)
        np.testing.assert_allclose(np.asarray(aligned.translations),
                                   np.asarray(rig.translations), atol=1e-12)


@pytest.mark.parametrize("degrees", [0.004, 0.013, 0.6, 179.0])
def test_pose_change_resolves_small_turns_of_float32_poses(degrees):
    """A camera turned by a known angle about a random axis, poses stored in float32 as the
    refinement keeps them: the reported angle is the turn's to float32 accuracy, also under
    the 0.02 degree that an arccos of the trace cannot resolve in float32."""
    rng = np.random.default_rng(int(degrees * 1000))
    rig = triangle_rig()
    axis = rng.normal(size=3)
    turned = turn(rig, 1, axis, degrees)
    f32 = [r.replace(rotations=jnp.asarray(r.rotations, jnp.float32)) for r in (rig, turned)]
    moved = ref.pose_change(*f32)["rotation_deg"]
    assert moved[0] == pytest.approx(0.0, abs=2e-5) and moved[2] == pytest.approx(0.0, abs=2e-5)
    assert moved[1] == pytest.approx(degrees, abs=2e-5)


def test_pose_gradient_matches_central_differences(quick_compiles_here):
    """d loss / d (rotation, translation) in float64 against central differences, at a pose
    a fraction of a degree off (bilinear samples away from pixel centres)."""
    with jax.enable_x64(True):
        truth = triangle_rig()
        images, masks = frames(truth)
        images, masks = images[:1].astype(np.float64), masks[:1].astype(np.float64)
        prepared = ref.prepare_images(jnp.asarray(images[0]), jnp.asarray(masks[0]), 1.0, 3)[None]
        pano = Panorama.hemisphere(*PANO_HW)
        rng = np.random.default_rng(7)
        params = ref.initial_parameters(truth, np.log(true_inverse_distance(1)))
        params["rotation"] = jnp.asarray(rng.normal(size=(2, 3)) * 0.004)
        params["translation"] = jnp.asarray(rng.normal(size=(2, 3)) * 0.004)
        jm = jnp.asarray(masks)

        def loss(rot, trans):
            p = dict(params, rotation=rot, translation=trans)
            return ref.refinement_loss(p, truth, prepared, jm, pano)[0]

        f = jax.jit(loss)
        grad = jax.jit(jax.grad(loss, argnums=(0, 1)))(params["rotation"], params["translation"])
        # Within 0.1 % of the gradient's largest component: a sample crossing a pixel centre
        # between the two difference points changes the bilinear slope there.
        tol = 1e-3 * max(float(jnp.max(jnp.abs(g))) for g in grad)
        h = 1e-6
        for which, g in enumerate(grad):
            for idx in np.ndindex(2, 3):
                e = jnp.zeros((2, 3)).at[idx].set(h)
                args = [params["rotation"], params["translation"]]
                hi = list(args)
                lo = list(args)
                hi[which] = args[which] + e
                lo[which] = args[which] - e
                fd = (float(f(*hi)) - float(f(*lo))) / (2 * h)
                assert float(g[idx]) == pytest.approx(fd, rel=1e-4, abs=tol), (which, idx)
        assert float(jnp.max(jnp.abs(grad[0]))) > 1e-3     # the loss does depend on the pose


def test_pose_information_is_the_schur_complement_of_the_dense_gauss_newton_matrix(
        quick_compiles_here):
    """The matrix-free curvature against a dense assembly (float64): the Jacobian of every
    colour sample in poses and distances at once (``jax.jacfwd``), each point's ``J^T C J``
    with ``C`` the Hessian of its dispersion, weighted as the data term weighs the point,
    plus ``jax.hessian`` of the smoothness in the distances. ``pose`` is the pose block, and
    ``marginal`` the Schur complement with the distances' diagonal; without smoothness the
    distance block is diagonal (no point couples to another), so there it is exact."""
    from gijax.calibrate import constraint as con
    from gijax.sweep.consistency import view_dispersion

    with jax.enable_x64(True):
        truth = triangle_rig()
        images, masks = frames(truth)
        images, masks = images.astype(np.float64), masks.astype(np.float64)
        pano = Panorama.hemisphere(3, 5)      # odd width: the colouring's wrapped column
        prepared = jnp.stack([ref.prepare_images(jnp.asarray(im), jnp.asarray(m), 1.0, 3)
                              for im, m in zip(images, masks)])
        jm = jnp.asarray(masks)
        rng = np.random.default_rng(3)
        params = ref.initial_parameters(truth, np.log(np.stack(
            [np.full(pano.shape, 1.0 / r) for r in RADII])) + 0.05 * rng.normal(
            size=(len(RADII), *pano.shape)))
        params["rotation"] = jnp.asarray(rng.normal(size=(2, 3)) * 0.003)
        params["translation"] = jnp.asarray(rng.normal(size=(2, 3)) * 0.003)
        guides = jnp.asarray(rng.uniform(0.2, 0.8, (len(RADII), *pano.shape, 3)))
        n_pose, shape = 12, params["log_inv"].shape

        def split(v):
            return dict(params, rotation=v[:6].reshape(2, 3), translation=v[6:12].reshape(2, 3),
                        log_inv=v[12:].reshape(shape))

        def samples(v):
            p = split(v)
            rig = ref.apply_calibration(truth, p)
            return jax.vmap(lambda im, m, li: ref.frame_samples(rig, im, m, li, pano))(
                prepared, jm, p["log_inv"])

        def smooth(v, weight):
            return weight * ref.refinement_loss(split(v), truth, prepared, jm, pano, 1.0, 0.05,
                                                guides)[1]["smooth"]

        flat = jnp.concatenate([params[k].reshape(-1)
                                for k in ("rotation", "translation", "log_inv")])
        cols, wts = (np.asarray(x) for x in samples(flat))       # (F, N, H, W, 3), (F, N, H, W)
        jac = np.asarray(jax.jacfwd(lambda v: samples(v)[0])(flat))  # (F, N, H, W, 3, D)
        point_c = jax.jit(jax.hessian(
            lambda c, w: view_dispersion(c[:, None, :], w[:, None])[0][0]))
        seen = wts.sum(1) >= ref.SEEN_WEIGHT
        gn = np.zeros((flat.size, flat.size))
        for f, h, w in zip(*np.nonzero(seen)):
            c = np.asarray(point_c(cols[f, :, h, w], wts[f, :, h, w])).reshape(9, 9)
            j = jac[f, :, h, w].reshape(9, -1)
            gn += j.T @ c @ j / (len(RADII) * seen[f].sum())
        smooth_hessian = jax.jit(jax.hessian(smooth))
        info_fn = jax.jit(lambda p, s: con.pose_information(p, truth, prepared, jm, pano, s,
                                                            0.05, guides))
        for weight in (0.02, 0.0):
            dense = gn + np.asarray(smooth_hessian(flat, weight))
            info = jax.device_get(info_fn(params, jnp.float64(weight)))
            h_pp, h_pd = dense[:n_pose, :n_pose], dense[:n_pose, n_pose:]
            diag = np.diag(dense[n_pose:, n_pose:])
            keep = diag > 0
            schur = h_pp - (h_pd[:, keep] / diag[keep]) @ h_pd[:, keep].T
            scale = np.abs(h_pp).max()
            np.testing.assert_allclose(info["pose"], h_pp, rtol=1e-7, atol=1e-9 * scale)
            np.testing.assert_allclose(info["distance"].reshape(-1), diag, rtol=1e-7,
                                       atol=1e-9 * np.abs(diag).max())
            np.testing.assert_allclose(info["marginal"], schur, rtol=1e-7, atol=1e-9 * scale)
            off = dense[n_pose:, n_pose:] - np.diag(diag)
            if weight == 0.0:
                assert np.abs(off).max() <= 1e-12 * np.abs(diag).max()
            else:
                assert np.abs(off).max() > 1e-3 * np.abs(diag).max()   # the coupling is there
            # Gauss-Newton: positive semi-definite, and the re-fitted distances take
            # curvature away from the poses, never add any.
            assert np.linalg.eigvalsh(info["marginal"]).min() > -1e-9 * scale
            assert np.linalg.eigvalsh(h_pp - info["marginal"]).min() > -1e-9 * scale


def test_far_frames_constrain_translation_loosely_and_the_report_says_so():
    """The same textures on spheres 25x farther: a camera shift moves their images 25x less,
    so the predicted translation deviation grows several-fold while the rotation's does not,
    and only the far frames draw the one-line warning."""
    from gijax.calibrate import constraint as con

    truth = triangle_rig()
    config = ref.RefineConfig(steps=6, blur=(1.5, 0.7), pano_hw=PANO_HW, min_texture=0.01)
    reports = {}
    for name, scale in (("near", 1.0), ("far", 25.0)):
        radii = tuple(scale * r for r in RADII)
        ims, ms = zip(*(sphere_images(truth, r, f) for f, r in enumerate(radii)))
        inv = np.stack([np.full(PANO_HW, 1.0 / r) for r in radii])
        reports[name] = con.pose_constraint(truth, np.stack(ims), np.stack(ms), inv, config)
    near, far = (reports[k]["cameras"] for k in ("near", "far"))
    assert near[0]["sigma_translation_mm"] == 0.0          # camera 0 is the gauge
    for k in (1, 2):
        assert far[k]["sigma_translation_mm"] > 3.0 * near[k]["sigma_translation_mm"]
        assert far[k]["sigma_rotation_deg"] < 1.5 * near[k]["sigma_rotation_deg"]
        assert abs(np.linalg.norm(far[k]["weak_direction"]) - 1.0) < 1e-9
        assert 0.0 <= far[k]["absorbed"] <= 1.0
    # Bounds between the two: twice the near frames' largest deviation (the cameras are 0.4 m
    # apart), and a rotation bound neither reaches.
    share = 2.0 * max(c["sigma_translation_mm"] for c in near) / 400.0
    assert con.weak_constraint_lines(reports["near"], truth, share, 10.0) == []
    lines = con.weak_constraint_lines(reports["far"], truth, share, 10.0)
    assert len(lines) == 2 and lines[0].startswith("cam1: the frames constrain its pose loosely")
    assert "of its 400 mm to the nearest camera" in lines[0]
    text = con.constraint_lines(reports["far"])
    assert len(text) == 2 and text[1].startswith(f"  cam2: {far[2]['sigma_rotation_deg']:.3f} deg")


def test_a_camera_compares_only_the_points_it_sees():
    """A frame whose distance map holds a near patch (0.5 m) in front of a far background
    (4 m): with the occlusion test each camera's weights are its weights without it times the
    points' visibility from that camera's centre, some background points are hidden from the
    cameras off the reference point, and the frame's terms weigh the points by what the
    cameras see."""
    from gijax.geometry.panorama_frame import panorama_rays
    from gijax.geometry.visibility import visible_from

    rig = triangle_rig()
    images, masks = (x[0] for x in frames(rig))
    pano = Panorama.hemisphere(24, 96)
    inv = np.full(pano.shape, 0.25)
    inv[4:10, 20:32] = 2.0
    log_inv = jnp.asarray(np.log(inv), jnp.float32)
    args = (rig, jnp.asarray(images), jnp.asarray(masks), log_inv, pano)
    _, plain = (np.asarray(x) for x in ref.frame_samples(*args, occlusion=0.0))
    _, seen = (np.asarray(x) for x in ref.frame_samples(*args, occlusion=0.05))
    pts = np.asarray(rig.reference) + (1.0 / inv)[..., None] * np.asarray(
        panorama_rays(rig, pano, jnp.float32))
    hidden = 0
    for k in range(rig.num_cameras):
        vis = np.asarray(visible_from(jnp.asarray(pts, jnp.float32), rig.translations[k],
                                      pano.width, 0.05))
        np.testing.assert_allclose(seen[k], plain[k] * vis, rtol=1e-6, atol=1e-7)
        hidden += int(((plain[k] > 0.5) & (vis == 0)).sum())
    assert hidden > 10
    on = ref.frame_terms(*args, occlusion=0.05)
    off = ref.frame_terms(*args, occlusion=0.0)
    np.testing.assert_allclose(np.asarray(on["weight"]), seen.sum(0), rtol=1e-6)
    assert float(np.sum(on["weight"])) < float(np.sum(off["weight"])) - 10.0


def test_flattening_removes_a_vignetting_the_gain_cannot():
    """The same textured view through a lens 35 % darker at the rim (the renderer's strongest
    vignetting) and through a flat one: one gain per camera leaves them over 15 % apart
    towards the rim; divided by their neighbourhood's mean (a 40th of the width here) they
    agree within a few percent."""
    truth = triangle_rig()
    images, masks = sphere_images(truth, 2.0, 0)
    flat_view, m = images[0].astype(np.float32), masks[0].astype(np.float32)
    yy, xx = np.mgrid[0:SIZE, 0:SIZE]
    rim = np.hypot(xx - (SIZE - 1) / 2, yy - (SIZE - 1) / 2) / (SIZE / 2)
    dark = flat_view * (1.0 - 0.35 * np.clip(rim, 0, 1) ** 2)[..., None]
    pair, pair_m = jnp.asarray(np.stack([flat_view, dark])), jnp.asarray(np.stack([m, m]))
    inner = (rim < 0.9) & (m > 0)

    def gap(out):
        out = np.asarray(out)
        return np.max(np.abs(out[1] - out[0])[inner] / np.maximum(out[0][inner], 1e-3))

    sigma = 0.05 * SIZE
    plain = ref.prepare_images(pair, pair_m, 0.7, 3)
    flat = ref.prepare_images(pair, pair_m, 0.7, 3, sigma, ref.blur_radius(sigma))
    assert gap(plain) > 0.15 and gap(flat) < 0.05, (gap(plain), gap(flat))   # 0.21, 0.03


def test_black_image_is_refused_with_one_line():
    truth = triangle_rig()
    images, masks = frames(truth)
    images[1, 2] = 0.0
    with pytest.raises(ValueError, match=r"^frame 1: camera cam2 has intensity contrast 0\.0000 "
                                         r"\(std .*\), below 0\.02: too little texture"):
        ref.refine_rig(truth, images, masks, ref.RefineConfig(steps=3, pano_hw=PANO_HW),
                       initial_inv=true_inverse_distance(), progress=False)


def test_frame_without_overlap_is_refused_with_one_line():
    # Narrow lenses looking +x, -x and -y: no panorama point is seen by two cameras.
    rots = np.stack([np.asarray(axis_angle_to_matrix(jnp.asarray(v, jnp.float32)))
                     for v in ([0.0, math.pi / 2, 0.0], [0.0, -math.pi / 2, 0.0],
                               [math.pi / 2, 0.0, 0.0])])
    rig = triangle_rig(rotations=rots, fov_deg=60.0)
    images, masks = frames(rig)
    with pytest.raises(ValueError, match=r"^frame 0: 0\.0% of the panorama is seen by two "
                                         r"cameras .*below 5\.0%: too little overlap"):
        ref.refine_rig(rig, images, masks, ref.RefineConfig(steps=3, pano_hw=PANO_HW),
                       initial_inv=np.stack([np.full((2 * PANO_HW[0], PANO_HW[1]), 0.5)] * 2),
                       progress=False)


def _write_frames(tmp_path, rig, images):
    import cv2

    folders = []
    for f, frame in enumerate(images):
        folder = tmp_path / f"frame{f}"
        folder.mkdir()
        for name, img in zip(rig.names, frame):
            u8 = np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)
            cv2.imwrite(str(folder / f"{name}.png"), u8[..., ::-1])
        folders.append(str(folder))
    return folders


def test_command_writes_the_refined_rig_and_its_report(tmp_path, capsys, quick_compiles_here,
                                                       monkeypatch):
    """Two rounds: the second starts from the classical baseline's distances (a stand-in
    here, so that no matcher compiles); the report says how far it moved the cameras."""
    import json

    from gijax.cli import main
    from gijax.io.rigfile import load_rig, save_rig

    monkeypatch.setattr(ref, "initial_inverse_distance",
                        lambda rig, image, mask, pano: np.full(pano.shape, 0.5))
    truth = triangle_rig()
    images, _ = frames(truth)
    start = turn(truth, 2, (1.0, 0.0, 0.0), 1.0)
    save_rig(start, tmp_path / "start.yaml")
    folders = _write_frames(tmp_path, truth, images)
    out, report, png = tmp_path / "refined.yaml", tmp_path / "report.json", tmp_path / "loss.png"
    rc = main(["rig", "refine", str(tmp_path / "start.yaml"), "--frames", *folders, "--out",
               str(out), "--steps", "6", "--rounds", "2", "--scale", "1", "--start-distance",
               "2", "--plot", str(png), "--json", str(report), "--no-progress"])
    text = capsys.readouterr().out
    assert rc == 0, text
    refined = load_rig(out)
    np.testing.assert_allclose(np.asarray(refined.rotations[0]), np.asarray(start.rotations[0]),
                               atol=1e-7)
    doc = json.loads(report.read_text())
    assert [c["name"] for c in doc["cameras"]] == ["cam0", "cam1", "cam2"]
    assert doc["cameras"][0]["rotation_deg"] == 0.0
    assert doc["cameras"][2]["rotation_deg"] > 0.0
    assert len(doc["history"]) == 12 and doc["rounds"] == 2
    assert [h["round"] for h in doc["history"]] == [0] * 6 + [1] * 6
    assert len(doc["round_moves"]) == 1 and len(doc["round_moves"][0]["translation_mm"]) == 3
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "cam2:" in text and "photometric loss:" in text and "gauge: camera 0" in text
    assert "(6 steps in each of 2 rounds)" in text
    moved = max(doc["round_moves"][0]["translation_mm"])
    assert "round 2 moved the cameras by at most" in text and f"and {moved:.2f} mm" in text
    # The constraint report: camera 0 is the gauge, the others' deviations printed as stored.
    cons = doc["constraint"]["cameras"]
    assert cons[0]["sigma_translation_mm"] == 0.0 and len(cons) == 3
    assert f"  cam2: {cons[2]['sigma_rotation_deg']:.3f} deg, " \
        f"{cons[2]['sigma_translation_mm']:.2f} mm along" in text
    assert "how well the frames fix each pose" in text


def test_command_names_a_missing_camera_image(tmp_path, capsys):
    from gijax.cli import main
    from gijax.io.rigfile import save_rig

    truth = triangle_rig()
    images, _ = frames(truth)
    save_rig(truth, tmp_path / "rig.yaml")
    folders = _write_frames(tmp_path, truth, images[:1])
    (tmp_path / "frame0" / "cam1.png").unlink()
    rc = main(["rig", "refine", str(tmp_path / "rig.yaml"), "--frames", *folders, "--out",
               str(tmp_path / "out.yaml"), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert len(err) == 1 and "no image for camera 'cam1'" in err[0] and "frame0" in err[0], err
    assert not (tmp_path / "out.yaml").exists()


def test_command_smoothness_option_reaches_the_refinement_and_refuses_a_negative_weight(
        tmp_path, capsys):
    """--smoothness is the objective's weight (its help states RefineConfig's default); a
    negative weight is one line naming the field, and no rig file is written."""
    from gijax.cli import main
    from gijax.io.rigfile import save_rig

    with pytest.raises(SystemExit):
        main(["rig", "refine", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert f"(default {ref.RefineConfig().smoothness}, RefineConfig's;" in help_text
    truth = triangle_rig()
    images, _ = frames(truth)
    save_rig(truth, tmp_path / "rig.yaml")
    folders = _write_frames(tmp_path, truth, images[:1])
    argv = ["rig", "refine", str(tmp_path / "rig.yaml"), "--frames", *folders, "--out",
            str(tmp_path / "out.yaml"), "--steps", "3", "--scale", "1", "--start-distance", "2",
            "--no-progress"]
    assert main(argv + ["--smoothness", "-1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "RefineConfig.smoothness must be >= 0; found -1.0" in err[0], err
    assert not (tmp_path / "out.yaml").exists()
    assert main(argv + ["--rounds", "0"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["gijax rig: error: --rounds must be at least 1; found 0"], err
    assert main(argv + ["--flatten", "0.5"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["gijax rig: error: --flatten must be in [0, 0.5); found 0.5"], err
    assert f"(default {ref.RefineConfig().flatten}, RefineConfig's;" in help_text
    assert main(argv + ["--occlusion", "1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["gijax rig: error: --occlusion must be in [0, 1); found 1.0"], err
    assert f"(default {ref.RefineConfig().occlusion}, RefineConfig's;" in help_text
    assert not (tmp_path / "out.yaml").exists()


def test_experiment_perturbation_is_within_its_stated_bounds():
    from experiments.calibration_refinement import perturb
    from gijax.geometry.layouts import layout_rig

    square = np.array([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]])
    truth = layout_rig(square, np.zeros(3), masks=False)
    for seed in (0, 1):
        moved = ref.pose_change(truth, perturb(truth, seed))
        assert moved["rotation_deg"][0] == 0.0 and moved["translation_mm"][0] == 0.0
        assert all(0.5 - 1e-3 <= a <= 2.0 + 1e-3 for a in moved["rotation_deg"][1:]), moved
        assert all(10.0 - 1e-3 <= t <= 30.0 + 1e-3 for t in moved["translation_mm"][1:]), moved


def test_experiment_report_draws_each_perturbed_camera_and_tables_every_camera(tmp_path):
    """The experiment's figure and table from two rows of known errors (the figure is a PNG
    of the size drawn; the table has a line per camera with the before -> after figures)."""
    from experiments.calibration_refinement import plot, table

    rows = [{"rig": rig, "seed": 0, "cameras": cams, "start_rotation_deg": [0.0] + [1.0] * k,
             "final_rotation_deg": [0.0] + [0.05] * k, "start_translation_mm": [0.0] + [20.0] * k,
             "final_translation_mm": [0.0] + [2.5] * k, "mae_true": 0.1, "mae_perturbed": 0.15,
             "mae_refined": 0.1025, "mae_aligned": 0.101,
             "held_out": {"true": {"mae": 0.08}, "perturbed": {"mae": 0.12},
                          "refined": {"mae": 0.09}, "aligned": {"mae": 0.082}},
             "held_out_paired": {"mean": 0.002, "ci95": [-0.001, 0.004], "lower": 3,
                                 "scenes": 16},
             "constraint": {"cameras": [{}] + [{"sigma_rotation_deg": 0.012,
                                                "sigma_translation_mm": 0.75,
                                                "absorbed": 0.5}] * k},
             "from_truth_rotation_deg": [0.0] + [0.02] * k,
             "from_truth_translation_mm": [0.0] + [1.25] * k}
            for rig, cams, k in (("a", ["c0", "c1", "c2"], 2), ("b", ["c0", "c1"], 1))]
    plot(rows, tmp_path / "errors.png")
    with open(tmp_path / "errors.png", "rb") as f:
        head = f.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    assert (int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")) == (1210, 484)
    lines = table(rows).splitlines()
    assert len(lines) == 2 + 5
    assert "| a | 0 | c1 | 1.000 -> 0.050 | 20.0 -> 2.5 | 0.012 / 0.75 (50 %) | 0.020 / 1.2 |" \
        in lines[3], lines[3]
    assert "| a | 0 | c0 | 0.000 -> 0.000 | 0.0 -> 0.0 | (gauge) | 0.000 / 0.0 |" in lines[2]
    assert "| 0.1000 / 0.1500 / 0.1025 / 0.1010 | 0.0800 / 0.1200 / 0.0900 / 0.0820 | +2.5 %; " \
        "per scene +0.0020 1/m " \
        "(95 % CI -0.0010..+0.0040), lower on 3/16 |" in lines[2], lines[2]


def test_a_dataset_folder_reads_as_one_frame_per_sample(tmp_path):
    from gijax.calibrate.frames import read_frames
    from gijax.data.writer import write_dataset

    rig = triangle_rig()
    images, masks = frames(rig)
    pano = Panorama.hemisphere(4, 16)

    def sample(i):
        return {"images": np.round(images[i] * 255).astype(np.uint8),
                "distances": np.full(images.shape[1:4], RADII[i], np.float32),
                "masks": masks[i].astype(np.uint8),
                "pano_distance": np.full(pano.shape, RADII[i], np.float32)}

    write_dataset(tmp_path / "d", sample, rig, pano, num_samples=2)
    got, got_masks, labels = read_frames([tmp_path / "d"], rig)
    assert labels == [f"{tmp_path / 'd'}#0", f"{tmp_path / 'd'}#1"]
    np.testing.assert_array_equal(got, np.round(images * 255).astype(np.uint8))
    np.testing.assert_array_equal(got_masks, masks)
    one, _, _ = read_frames([tmp_path / "d"], rig, max_frames=1)
    assert one.shape[0] == 1


def test_default_working_scale_and_implausible_moves():
    """The default working size is REFINE_WIDTH wide without enlarging (and --help says so);
    a camera that moved more than half its distance to the nearest camera, or more than 5
    degrees, is named, one that moved less is not."""
    from gijax.cli import build_parser

    assert ref.refine_scale(1024) == 0.25 and ref.refine_scale(ref.REFINE_WIDTH) == 1.0
    assert ref.refine_scale(128) == 1.0 and ref.refine_scale(1280) == ref.REFINE_WIDTH / 1280
    parser = build_parser()
    rig_action = next(a for a in parser._subparsers._group_actions[0].choices["rig"]
                      ._subparsers._group_actions)
    help_text = rig_action.choices["refine"].format_help()
    assert f"{ref.REFINE_WIDTH} px wide" in " ".join(help_text.split())
    cam = make_camera("equidistant", {"fx": 80.0, "fy": 80.0, "cx": 63.5, "cy": 63.5}, 128, 128)
    # Three cameras on a line, 70 mm apart: cam2's nearest camera is 70 mm away.
    rig = make_rig([cam] * 3, np.stack([np.eye(3)] * 3), [[0, 0, 0], [0.07, 0, 0], [0.14, 0, 0]])
    moved = {"rotation_deg": [0.0, 6.0, 0.3], "translation_mm": [0.0, 10.0, 36.0]}
    lines = ref.implausible_moves(rig, moved)
    assert len(lines) == 2 and lines[0].startswith(rig.names[1] + " moved 6.00 deg")
    assert lines[1].startswith(rig.names[2]) and "0.5x its 70 mm" in lines[1]
    assert ref.implausible_moves(rig, {"rotation_deg": [0, 4.9, 0.3],
                                       "translation_mm": [0, 34.9, 34.9]}) == []
