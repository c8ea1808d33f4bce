"""The matching-cost channel (gijax.sweep.matching, the match grids, ``matching_cost='zncc'``)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gijax.geometry.panorama import Panorama, lonlat_grid
from gijax.sweep.matching import TEXTURE_EPS, cell_zncc

pytestmark = pytest.mark.usefixtures("quick_compiles")


def _reference_zncc(grey, seen, k):
    """Mean of NumPy's Pearson correlation over the pairs of cameras that see the whole cell."""
    b, n, d, hh, ww = grey.shape
    out = np.zeros((b, d, hh // k, ww // k))
    for bi, di, i, j in np.ndindex(*out.shape):
        cell = (slice(i * k, (i + 1) * k), slice(j * k, (j + 1) * k))
        patches = [grey[bi, c, di][cell].ravel() for c in range(n)
                   if seen[bi, c, di][cell].min() > 0]
        values = [np.corrcoef(p, q)[0, 1] for x, p in enumerate(patches) for q in patches[x + 1:]]
        out[bi, di, i, j] = np.mean(values) if values else 0.0
    return out


@pytest.mark.parametrize("seed", range(3))
def test_cell_zncc_is_the_mean_pairwise_correlation(seed):
    rng = np.random.default_rng(seed)
    k = (2, 3, 4)[seed]
    grey = rng.uniform(size=(2, 4, 3, 2 * k, 3 * k))
    # Whole cameras out, single points out (the camera then sits the cell out), and cells that
    # only one camera sees.
    seen = (rng.uniform(size=grey.shape) > 0.04).astype(np.float64)
    seen[0, 1] = 0.0
    seen[1, :3, 0, :k, :k] = 0.0
    got = np.asarray(cell_zncc(jnp.asarray(grey, jnp.float32), jnp.asarray(seen, jnp.float32),
                               k, eps=0.0))
    want = _reference_zncc(grey, seen, k)
    np.testing.assert_allclose(got, want, atol=2e-6)
    assert got[1, 0, 0, 0] == 0.0          # one camera left: no pair


def test_cell_zncc_ignores_each_cameras_gain_and_offset_and_sees_mirrors():
    """Per camera and cell, ``a x + c`` (a > 0) leaves the correlation unchanged; identical
    textured patches correlate to 1 (up to the texture regulariser), a negated one to -1."""
    rng = np.random.default_rng(5)
    k = 4
    base = rng.uniform(0.3, 0.7, size=(1, 1, 2, k, 2 * k))
    gain = rng.uniform(0.5, 2.0, size=(1, 3, 2, 1, 1))
    offset = rng.uniform(-0.2, 0.2, size=(1, 3, 2, 1, 1))
    seen = jnp.ones((1, 3, 2, k, 2 * k), jnp.float32)
    same = cell_zncc(jnp.asarray(np.repeat(base, 3, 1), jnp.float32), seen, k)
    affine = cell_zncc(jnp.asarray(gain * base + offset, jnp.float32), seen, k, eps=0.0)
    np.testing.assert_allclose(np.asarray(affine), 1.0, atol=1e-5)
    # Identical patches with the regulariser: |z|^2 / (|z|^2 + eps k^2) exactly.
    cells = base[0, 0].reshape(2, 1, k, 2, k).transpose(0, 1, 3, 2, 4).reshape(2, 1, 2, k * k)
    sq = np.sum((cells - cells.mean(-1, keepdims=True)) ** 2, -1)
    np.testing.assert_allclose(np.asarray(same)[0], sq / (sq + TEXTURE_EPS * k * k), atol=1e-6)
    mirror = np.concatenate([base, 1.0 - base], axis=1)
    got = cell_zncc(jnp.asarray(mirror, jnp.float32), seen[:, :2], k, eps=0.0)
    np.testing.assert_allclose(np.asarray(got), -1.0, atol=1e-5)


def test_cell_zncc_is_finite_with_finite_gradients_on_flat_patches():
    flat = jnp.full((1, 3, 2, 4, 8), 0.5)
    seen = jnp.ones_like(flat)
    assert np.all(np.asarray(cell_zncc(flat, seen, 4)) == 0.0)
    g = jax.grad(lambda x: jnp.sum(cell_zncc(x, seen, 4)))(flat)
    assert np.all(np.isfinite(np.asarray(g)))
    with pytest.raises(ValueError, match="do not split into cells of 3 x 3"):
        cell_zncc(flat, seen, 3)


def test_match_grid_points_are_the_sub_cell_centres():
    """The match panorama's k x k pixels of a cost cell average to the cell's own centre (in
    latitude and, away from the seam, longitude): the sub-cells tile the cell."""
    from gijax.sweep.grids import match_grids

    cost = Panorama(4, 8, 0.1, 1.2)
    k = 3
    lon_f, lat_f = (np.asarray(a, np.float64) for a in lonlat_grid(
        Panorama(cost.height * k, cost.width * k, cost.lat_min, cost.lat_max)))
    lon_c, lat_c = (np.asarray(a, np.float64) for a in lonlat_grid(cost))
    block = lambda a: a.reshape(cost.height, k, cost.width, k).mean(axis=(1, 3))
    np.testing.assert_allclose(block(lat_f), lat_c, atol=1e-6)
    np.testing.assert_allclose(block(lon_f), lon_c, atol=1e-6)
    # The grids are the sweep at those points, in surrogate pixels.
    from test_model import rig_from, tri_positions

    rig = rig_from(tri_positions()[:2], tri_positions()[0])
    px, ok = match_grids(rig, jnp.asarray([1.0, 3.0]), Panorama.hemisphere(4, 8), (16, 32), 2)
    assert px.shape == (2, 2, 8, 16, 2) and ok.shape == (2, 2, 8, 16)
    with pytest.raises(ValueError, match="at least 1 sample"):
        match_grids(rig, jnp.asarray([1.0, 3.0]), Panorama.hemisphere(4, 8), (16, 32), 0)


def test_matching_channel_peaks_at_the_true_distance_of_a_rendered_sphere():
    """Cameras looking at a textured sphere of radius r around the reference point: for most
    cells seen by two or more cameras, the candidate with the highest correlation is r or its
    neighbour, far above the 1 in 16 of a cue unrelated to the geometry (the renderer varies
    gain, white balance and vignetting and adds sensor noise per camera; images at 1/8 of the
    paper's size)."""
    from gijax.geometry.layouts import builtin_rig
    from gijax.geometry.rig import scale_rig
    from gijax.render import render_fronto_plane
    from gijax.sweep.grids import (fisheye_surrogates, match_grey, surrogate_resampling,
                                   sweep_grids)

    rig = scale_rig(builtin_rig("paper-train"), 0.125)
    cand = np.asarray([0.6, 0.8, 1.0, 1.4, 2.0, 3.0, 5.0, 10.0, 14.0, 20.0, 25.0, 30.0, 40.0,
                       50.0, 70.0, 100.0], np.float32)
    truth = list(cand).index(2.0)
    sample = render_fronto_plane(rig, 2.0, seed=3, pano=Panorama.hemisphere(16, 64))
    surrogate_hw = (64, 256)

    @jax.jit
    def cue(rig, images, masks):
        sur, sur_masks = fisheye_surrogates(surrogate_resampling(rig, surrogate_hw), images,
                                            masks)
        grids = sweep_grids(rig, jnp.asarray(cand), Panorama.hemisphere(8, 32), (16, 64), None,
                            surrogate_hw, match_samples=4)
        return cell_zncc(*match_grey(sur, sur_masks, grids), 4)

    ncc = np.asarray(cue(rig, jnp.asarray(sample["images"][None], jnp.float32) / 255.0,
                         jnp.asarray(sample["masks"][None], jnp.float32)))[0]   # (D, h, w)
    paired = np.any(ncc != 0.0, axis=0)
    assert paired.mean() > 0.5
    best = np.argmax(ncc, axis=0)[paired]
    assert np.mean(best == truth) > 0.4, np.bincount(best, minlength=16)
    assert np.mean(np.abs(best - truth) <= 1) > 0.65, np.bincount(best, minlength=16)


def test_matching_cost_model_feeds_one_more_channel_and_trains():
    """``matching_cost='zncc'``: the cost volume's conv takes the feature channels and the
    matching channel; the loss's gradient is finite and reaches every weight."""
    from flax import nnx

    from gijax.model import count_parameters, create_model, model_grids
    from gijax.nn.presets import ModelConfig
    from gijax.train.losses import model_loss
    from test_model import G8, TINY_VAR, inputs, rig_from, tri_positions

    cfg = dataclasses.replace(TINY_VAR, name="tiny-zncc", matching_cost="zncc",
                              matching_samples=2)
    model = create_model(cfg, seed=1)
    model.eval()
    c = cfg.feature_channels
    assert model.cost_volume.fuse.conv.kernel[...].shape[-2] == c + 1
    assert count_parameters(cfg)["cost"] - count_parameters(TINY_VAR)["cost"] == 27 * cfg.unet_in
    pos = tri_positions()
    rig = rig_from(pos, pos[0])
    sur, m = inputs(3, 2)
    grids = model_grids(cfg, rig, jnp.asarray(G8))
    assert grids.match_px.shape == (3, 8, 16, 64, 2)
    distance = jnp.full((2, *cfg.output_hw), 2.0)
    valid = jnp.ones((2, *cfg.output_hw), bool)
    graphdef, params, rest = nnx.split(model, nnx.Param, ...)

    def loss(p):
        out = nnx.merge(graphdef, p, rest)(sur, m, grids)
        return model_loss("volume", out, distance, valid, grids.candidates)

    grads = jax.tree_util.tree_leaves(jax.jit(jax.grad(loss))(params))
    assert all(np.all(np.isfinite(np.asarray(g))) for g in grads)
    assert all(np.abs(np.asarray(g)).max() > 0 for g in grads)
    with pytest.raises(ValueError, match="matching_cost"):
        dataclasses.replace(TINY_VAR, matching_cost="sad")
    assert isinstance(cfg, ModelConfig)
