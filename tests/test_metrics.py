"""Metrics against hand values and an independent scipy.ndimage SSIM."""

import jax.numpy as jnp
import numpy as np
from scipy import ndimage

from gijax.train.metrics import evaluate_batch, ssim_map

CAND = jnp.array([0.5, 1.0, 2.0, 4.0], jnp.float32)      # inverse range 0.25..2


def test_mae_rmse_bad_hand_values():
    # labels 1 m, 2 m, 0.1 m (clamped to 1/0.5 = 2), 1e6 m (clamped to 0.25), invalid one
    dist = jnp.asarray([[[1.0, 2.0, 0.1, 1e6, 1.0]]])
    inv = jnp.asarray([[[1.2, 0.5, 1.5, 0.25, 9.0]]])
    valid = jnp.asarray([[[1, 1, 1, 1, 0]]])
    m = evaluate_batch(inv, dist, valid, CAND)
    errs = np.array([0.2, 0.0, 0.5, 0.0])
    assert abs(m["mae"] - errs.mean()) < 1e-6
    assert abs(m["rmse"] - np.sqrt((errs ** 2).mean())) < 1e-6
    assert abs(m["bad_0.1"] - 2 / 4) < 1e-9 and abs(m["bad_0.4"] - 1 / 4) < 1e-9
    assert m["pixels"] == 4


def _ssim_reference(x, y, data_range=1.0):
    """Direct SSIM: a 2-D Gaussian built from its formula, correlated with zero padding."""
    r = np.arange(11) - 5.0
    yy, xx = np.meshgrid(r, r, indexing="ij")
    w = np.exp(-(xx ** 2 + yy ** 2) / (2 * 1.5 ** 2))
    w /= w.sum()

    def f(a):
        return ndimage.correlate(a, w, mode="constant", cval=0.0)

    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    mx, my = f(x), f(y)
    vx, vy, cxy = f(x * x) - mx ** 2, f(y * y) - my ** 2, f(x * y) - mx * my
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx ** 2 + my ** 2 + c1) * (vx + vy + c2))
    return s


def test_ssim_matches_independent_reference():
    rng = np.random.default_rng(0)
    h, w = 24, 40
    yy, xx = np.mgrid[0:h, 0:w]
    a = 0.5 + 0.4 * np.sin(xx / 4.0) * np.cos(yy / 5.0)
    b = a + 0.08 * rng.standard_normal((h, w))
    c = rng.uniform(0.01, 2.0, (h, w))
    for x, y, rng_ in [(a, b, 1.0), (a, c, 1.0), (b, c, 2.0)]:
        got = np.asarray(ssim_map(jnp.asarray(x[None], jnp.float32), jnp.asarray(y[None], jnp.float32),
                                  data_range=rng_))[0]
        ref = _ssim_reference(x, y, rng_)
        np.testing.assert_allclose(got, ref, atol=2e-4)
    same = float(jnp.mean(ssim_map(jnp.asarray(a[None]), jnp.asarray(a[None]))))
    assert abs(same - 1.0) < 1e-5
    # batch metric: whole-image mean of the map, labels given as distances 1 / a
    m = evaluate_batch(jnp.asarray(b[None], jnp.float32), jnp.asarray(1.0 / a[None], jnp.float32),
                       jnp.ones((1, h, w)), jnp.array([0.5, 1.0, 100.0]))
    ref = _ssim_reference(b, np.clip(a, 0.01, 2.0)).mean()
    assert abs(m["ssim"] - ref) < 2e-4, (m["ssim"], ref)
    assert m["ssim"] < 0.99
