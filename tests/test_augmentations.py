"""Photometric, body-outline and calibration augmentations against independent references:
closed forms, OpenCV, scipy's DCT, libjpeg (through OpenCV), sample statistics and loops."""

from __future__ import annotations

import argparse
import dataclasses
import math

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.fft

from gijax.data import photometric as ph
from gijax.data.augment import AUGMENT_PRESETS, AugmentConfig, augment_preset, augment_sample
from gijax.data.calibration_error import CalibrationError, perturb_rig
from gijax.geometry.layouts import builtin_rig

# Compiled without XLA's optimisation passes (conftest's quick_compiles): these checks do
# not depend on them, and they dominate this module's time.
pytestmark = pytest.mark.usefixtures("quick_compiles")

H, W = 16, 24
ALL_ON = AugmentConfig(p_vignetting=1.0, p_blur=1.0, p_colour=1.0, p_noise=1.0, p_jpeg=1.0,
                       p_body=1.0)
_augment = jax.jit(augment_sample, static_argnames=("config",))


def _images(seed=0, n=2, h=H, w=W):
    rng = np.random.default_rng(seed)
    images = rng.uniform(0.05, 0.95, (n, h, w, 3)).astype(np.float32)
    masks = (rng.uniform(size=(n, h, w)) > 0.1).astype(np.float32)
    return images, masks


def test_all_off_and_neutral_ranges_are_the_identity():
    images, masks = _images()
    key = jax.random.PRNGKey(3)
    off = dataclasses.replace(AugmentConfig(), exposure=(2.0, 3.0), blur_sigma=(2.0, 3.0))
    out_i, out_m = augment_sample(key, images, masks, off)
    np.testing.assert_array_equal(out_i, images)
    np.testing.assert_array_equal(out_m, masks)
    # Every stage on, with ranges that collapse to its neutral value, changes nothing either.
    neutral = AugmentConfig(p_vignetting=1.0, vignetting_strength=(0.0, 0.0), p_blur=1.0,
                            blur_sigma=(1e-4, 1e-4), p_colour=1.0, exposure=(1.0, 1.0),
                            white_balance=(1.0, 1.0), gamma=(1.0, 1.0), p_noise=1.0,
                            shot_gain=(0.0, 0.0), read_std=(0.0, 0.0))
    out_i, out_m = _augment(key, images, masks, neutral)
    np.testing.assert_allclose(out_i, images, atol=1e-6)
    np.testing.assert_array_equal(out_m, masks)


def test_noise_variance_follows_the_shot_plus_read_model():
    levels = (0.2, 0.7)
    image = np.concatenate([np.full((64, 32, 3), v, np.float32) for v in levels], axis=1)
    shot, read = 2e-3, 0.01
    out = np.asarray(ph.sensor_noise(jax.random.PRNGKey(0), jnp.asarray(image), shot, read))
    for half, level in zip((out[:, :32], out[:, 32:]), levels):
        x = half.ravel().astype(np.float64)
        n = x.size
        var = shot * level + read**2              # the model, written out
        # Sample variance of a normal: standard error var * sqrt(2 / (n - 1)); 5 of them.
        assert abs(x.var(ddof=1) - var) < 5 * var * math.sqrt(2.0 / (n - 1))
        assert abs(x.mean() - level) < 5 * math.sqrt(var / n)


def test_gaussian_blur_equals_opencv():
    rng = np.random.default_rng(1)
    image = rng.uniform(size=(13, 19, 3)).astype(np.float32)
    for sigma, radius in ((0.7, 3), (1.3, 4)):
        ours = np.asarray(ph.gaussian_blur(jnp.asarray(image), sigma, radius))
        ref = cv2.GaussianBlur(image, (2 * radius + 1, 2 * radius + 1), sigmaX=sigma,
                               sigmaY=sigma, borderType=cv2.BORDER_REFLECT_101)
        np.testing.assert_allclose(ours, ref, atol=2e-6)


def test_exposure_and_white_balance_are_per_channel_gains():
    rng = np.random.default_rng(2)
    image = rng.uniform(0.0, 0.6, (5, 7, 3)).astype(np.float32)
    gains = np.array([0.9, 1.0, 1.15], np.float32)
    out = np.asarray(ph.exposure_white_balance(jnp.asarray(image), 1.4, gains, 1.0))
    np.testing.assert_allclose(out, image * 1.4 * gains, rtol=1e-6)
    # Saturation clips at 1; gamma is a power of the clipped signal.
    out = np.asarray(ph.exposure_white_balance(jnp.asarray(image), 2.5, gains, 0.8))
    np.testing.assert_allclose(out, np.minimum(image * 2.5 * gains, 1.0) ** 0.8, rtol=2e-6)


def test_vignetting_equals_the_closed_form():
    image = np.full((9, 12, 3), 0.8, np.float32)
    centre, radius, strength = (5.5, 3.0), 4.5, 0.4
    out = np.asarray(ph.vignetting(jnp.asarray(image), centre, radius, strength))
    for u, v in ((0, 0), (5, 3), (11, 8), (3, 7)):
        r2 = ((u - 5.5) ** 2 + (v - 3.0) ** 2) / 4.5**2
        np.testing.assert_allclose(out[v, u], 0.8 / (1.0 + 0.4 * r2) ** 2, rtol=1e-6)


def _quantise_reference(plane: np.ndarray, table: np.ndarray) -> np.ndarray:
    out = np.empty_like(plane, dtype=np.float64)
    for r in range(0, plane.shape[0], 8):
        for c in range(0, plane.shape[1], 8):
            coeffs = scipy.fft.dctn(plane[r:r + 8, c:c + 8].astype(np.float64), norm="ortho")
            out[r:r + 8, c:c + 8] = scipy.fft.idctn(np.round(coeffs / table) * table,
                                                    norm="ortho")
    return out


def test_block_dct_quantiser_equals_scipy():
    rng = np.random.default_rng(4)
    plane = rng.uniform(-128, 127, (16, 24)).astype(np.float32)
    # libjpeg's quality scaling, by hand: q = 50 is the table itself, q = 75 halves it.
    np.testing.assert_array_equal(ph.quality_table(ph.LUMA_TABLE, 50), ph.LUMA_TABLE)
    assert float(ph.quality_table(ph.LUMA_TABLE, 75)[0, 0]) == math.floor((16 * 50 + 50) / 100)
    assert float(ph.quality_table(ph.LUMA_TABLE, 10)[7, 7]) == 255     # 99 * 500 clipped
    for q in (30, 80):
        table = np.asarray(ph.quality_table(ph.LUMA_TABLE, q))
        ours = np.asarray(ph.block_dct_quantise(jnp.asarray(plane), jnp.asarray(table)))
        np.testing.assert_allclose(ours, _quantise_reference(plane, table), atol=2e-3)


def test_jpeg_matches_libjpeg_and_improves_with_quality():
    rng = np.random.default_rng(5)
    smooth = cv2.GaussianBlur(rng.uniform(size=(24, 32, 3)).astype(np.float32), (7, 7), 1.5)
    u8 = np.round(smooth * 255).astype(np.uint8)
    errors = []
    for q in (20, 50, 90):
        ours = np.asarray(ph.jpeg_compress(jnp.asarray(u8 / 255.0, jnp.float32), q)) * 255
        ok, buf = cv2.imencode(".jpg", u8[..., ::-1], [
            cv2.IMWRITE_JPEG_QUALITY, q,
            cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444])
        ref = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].astype(np.float32)
        ours_err, ref_err = np.abs(ours - u8).mean(), np.abs(ref - u8).mean()
        # libjpeg's integer DCT differs from the exact one by about a level.
        assert np.abs(ours - ref).mean() < 1.2
        assert abs(ours_err - ref_err) < 0.15 * ref_err
        errors.append(ours_err)
    assert errors[0] > errors[1] > errors[2] > 0


def test_masks_only_lose_pixels_and_lost_pixels_are_black():
    images, masks = _images(6, n=2)
    lost_any = False
    for seed in range(3):
        out_i, out_m = (np.asarray(a) for a in _augment(jax.random.PRNGKey(seed), images,
                                                        masks, ALL_ON))
        assert np.all(out_m <= masks)
        lost = out_m < masks
        lost_any |= bool(lost.any())
        assert np.all(out_i[lost] == 0)
        assert 0.0 <= out_i.min() and out_i.max() <= 1.0
    assert lost_any
    # The photometric preset never touches masks.
    _, out_m = _augment(jax.random.PRNGKey(0), images, masks, AUGMENT_PRESETS["photometric"])
    np.testing.assert_array_equal(out_m, masks)


def _close(a, b):
    # JPEG rounds: a last-bit difference between compiled and eager arithmetic may move a
    # coefficient to the next step, which changes its 8 x 8 block; allow a few such pixels.
    diff = np.abs(np.asarray(a) - np.asarray(b))
    assert np.mean(diff > 1e-4) < 0.02 and diff.mean() < 1e-3


def test_the_loaders_compiled_sample_equals_the_batched_program():
    """The loader augments one sample at a time (compiled alone); a batch under vmap gives the
    same images for two cameras. (Compiled against eager, op by op: the transformation
    registry's ``augment_sample`` entry, tests/test_transforms.py.)"""
    images, masks = _images(7, n=2)
    keys = jnp.stack([jax.random.PRNGKey(s) for s in (11, 12)])
    batch_i = np.stack([images, images[::-1]])
    batch_m = np.stack([masks, masks[::-1]])
    vmapped = jax.jit(jax.vmap(lambda k, i, m: augment_sample(k, i, m, ALL_ON)))(
        keys, batch_i, batch_m)
    for b in range(2):
        for a, c in zip(_augment(keys[b], batch_i[b], batch_m[b], ALL_ON), vmapped):
            _close(a, c[b])


def test_unknown_augmentation_names_the_choices():
    with pytest.raises(ValueError, match="unknown augmentation 'sepia'; choose one of"):
        augment_preset("sepia")


def _angle_deg(a, b):
    c = (np.trace(a.T @ b) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def test_perturb_rig_keeps_rotations_orthonormal_within_bounds():
    rig = builtin_rig("paper-train")
    error = CalibrationError(rotation_deg=0.5, focal=0.01, centre=0.01)
    angles = []
    for seed in range(4):
        new = perturb_rig(jax.random.PRNGKey(seed), rig, error)
        r_old = np.asarray(rig.rotations, np.float64)
        r_new = np.asarray(new.rotations, np.float64)
        np.testing.assert_array_equal(new.translations, rig.translations)
        for i, (old_c, new_c) in enumerate(zip(rig.cameras, new.cameras)):
            np.testing.assert_allclose(r_new[i].T @ r_new[i], np.eye(3), atol=2e-6)
            assert abs(np.linalg.det(r_new[i]) - 1.0) < 2e-6
            angles.append(_angle_deg(r_old[i], r_new[i]))
            f = float(new_c.fx) / float(old_c.fx)
            assert abs(f - 1.0) <= 0.01 + 1e-6
            assert abs(float(new_c.fy) / float(old_c.fy) - f) < 1e-6
            assert abs(float(new_c.cx) - float(old_c.cx)) <= 0.01 * old_c.width + 1e-3
            assert abs(float(new_c.cy) - float(old_c.cy)) <= 0.01 * old_c.height + 1e-3
            assert (new_c.width, new_c.height) == (old_c.width, old_c.height)
    assert max(angles) <= 0.5 + 0.01          # acos near 1 in float32: 0.01 deg slack
    assert max(angles) > 0.1                   # the draws are not all tiny


def test_training_option_is_recorded_and_offered_on_the_command_line():
    from gijax.cli import cmd_train
    from gijax.train.config import TrainConfig

    parser = argparse.ArgumentParser()
    cmd_train.register(parser.add_subparsers())
    sub = parser._subparsers._group_actions[0].choices["train"]
    choices = next(a.choices for a in sub._actions if a.dest == "augment")
    assert sorted(choices) == sorted(AUGMENT_PRESETS)
    cfg = TrainConfig(augment="photometric")
    assert TrainConfig.from_dict(cfg.to_dict()).augment == "photometric"
    assert TrainConfig().augment == "none"


def test_loader_augments_training_but_not_validation(tmp_path):
    from test_data_format import PANO, synthetic_sample, tiny_rig

    from gijax.data.loader import Loader
    from gijax.data.reader import DatasetReader
    from gijax.data.writer import write_dataset
    from gijax.geometry.panorama import Panorama
    from gijax.train.sources import dataset_stream_factory, validation_batches

    rig = tiny_rig()
    write_dataset(tmp_path / "d", lambda i: synthetic_sample(rig, i), rig, PANO, num_samples=2)
    reader = DatasetReader(tmp_path / "d")
    sur = Panorama.hemisphere(8, 32)
    opts = dict(batch_size=2, seed=4, surrogate=sur, shuffle=False, workers=0, num_epochs=1)
    with Loader(reader, **opts) as plain:
        clean = next(plain)
    # Cheap stages keep the compile short; the stages themselves are tested above.
    preset = AugmentConfig(p_colour=1.0, p_noise=1.0, p_body=1.0)
    with Loader(reader, augment=preset, **opts) as a, Loader(reader, augment=preset, **opts) as b:
        first, again = next(a), next(b)
    assert np.abs(first["surrogates"] - clean["surrogates"]).mean() > 1e-3
    assert np.all(first["masks"] <= clean["masks"] + 1e-6)
    np.testing.assert_array_equal(first["surrogates"], again["surrogates"])   # keyed, not timed
    np.testing.assert_array_equal(first["distance"], clean["distance"])
    stream = dataset_stream_factory(reader, rig, 2, 4, (8, 32), augment=preset, workers=0)()
    try:
        train_batch = next(stream)
    finally:
        stream.close()
    assert list(clean["index"]) == [0, 1]
    same_samples = clean["surrogates"][train_batch["index"]]
    assert np.abs(train_batch["surrogates"] - same_samples).mean() > 1e-3
    val = next(validation_batches(reader, rig, 2, (8, 32)))
    np.testing.assert_array_equal(val["surrogates"], clean["surrogates"])
