"""Metrics against hand values and independent numpy / scipy computations: gijax's own set and
the paper's (the release's metric code, torchmetrics' SSIM before 1.5)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from gijax.evaluate.metrics import batch_sums, evaluate_batch, paper_ssim, ssim_map, summarize

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


# --------------------------------------------------------------------------- the paper's set
# References below follow the published algorithms (the release's metric code and
# torchmetrics' SSIM before 1.5) in plain numpy, float64, one sample at a time.

PAPER_CAND = np.array([0.5, 0.8, 2.0, 7.0, 100.0], np.float32)


def _paper_ssim_reference(pred, target):
    """torchmetrics (< 1.5) SSIM of one (H, W) pair with default arguments, in numpy."""
    pred, target = np.asarray(pred, np.float64), np.asarray(target, np.float64)
    r = np.arange(11) - 5.0
    yy, xx = np.meshgrid(r, r, indexing="ij")
    w = np.exp(-(xx ** 2 + yy ** 2) / (2 * 1.5 ** 2))
    w /= w.sum()
    L = max(np.ptp(pred), np.ptp(target))
    c1, c2 = (0.01 * L) ** 2, (0.03 * L) ** 2

    def blur(a):                      # reflect-pad by 5, then a 'valid' correlation
        p = np.pad(a, 5, mode="reflect")
        win = np.lib.stride_tricks.sliding_window_view(p, (11, 11))
        return np.einsum("ijkl,kl->ij", win, w)

    mx, my = blur(pred), blur(target)
    vx = np.maximum(blur(pred * pred) - mx ** 2, 0.0)
    vy = np.maximum(blur(target * target) - my ** 2, 0.0)
    cxy = blur(pred * target) - mx * my
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx ** 2 + my ** 2 + c1) * (vx + vy + c2))
    return s[5:-5, 5:-5].mean()


def _paper_reference(inv, dist, valid, cand):
    """The paper's dataset metrics: per-sample values in numpy, then means over samples."""
    lo, hi = float(cand[0]), float(cand[-1])
    maes, rmses, bads, ssims = [], [], {0.1: [], 0.4: []}, []
    for p, d, v in zip(np.asarray(inv, np.float64), np.asarray(dist, np.float64),
                       np.asarray(valid, bool)):
        usable = v & np.isfinite(d) & (d > 0)
        inside = usable & (d >= lo) & (d <= hi)
        if inside.any():
            e = p[inside] - 1.0 / d[inside]
            maes.append(np.abs(e).mean())
            rmses.append(np.sqrt((e ** 2).mean()))
            for t in bads:
                bads[t].append((np.abs(e) > t).mean())
        target = np.where(usable, np.clip(1.0 / np.where(usable, d, 1.0), 1 / hi, 1 / lo), p)
        ssims.append(_paper_ssim_reference(p, target))
    nan = float("nan")
    return {"mae": np.mean(maes) if maes else nan, "rmse": np.mean(rmses) if rmses else nan,
            "ssim": np.mean(ssims), "bad_0.1": np.mean(bads[0.1]) if maes else nan,
            "bad_0.4": np.mean(bads[0.4]) if maes else nan}


def _paper(inv, dist, valid, cand=PAPER_CAND):
    return evaluate_batch(jnp.asarray(inv, jnp.float32), jnp.asarray(dist, jnp.float32),
                          jnp.asarray(valid), jnp.asarray(cand), metric_set="paper")


def test_paper_range_boundaries_hand_values():
    # One row of pixels inside a 12 x 12 image whose other pixels are sky (excluded).
    dist = np.full((1, 12, 12), 1e6, np.float32)
    inv = np.full((1, 12, 12), 0.01, np.float32)
    valid = np.ones((1, 12, 12), bool)
    row = [(0.49, 1.0), (0.5, 1.5), (100.0, 0.06), (100.5, 0.5), (1.0, 1.25), (4.0, 0.25),
           (2.0, 9.0)]
    for j, (d, p) in enumerate(row):
        dist[0, 0, j], inv[0, 0, j] = d, p
    valid[0, 0, 6] = False                       # labelled 2 m but not usable
    m = _paper(inv, dist, valid)
    # In: 0.5 m (|1.5 - 2| = 0.5), 100 m (|0.06 - 0.01| = 0.05), 1 m (0.25), 4 m (0). Out:
    # 0.49 m (nearer than the nearest candidate), 100.5 m, the invalid pixel and all sky.
    errs = np.array([0.5, 0.05, 0.25, 0.0])
    assert m["pixels"] == 4 and m["samples"] == 1
    assert m["mae"] == pytest.approx(errs.mean(), abs=1e-6)
    assert m["rmse"] == pytest.approx(np.sqrt((errs ** 2).mean()), abs=1e-6)
    assert m["bad_0.1"] == pytest.approx(2 / 4)
    assert m["bad_0.4"] == pytest.approx(1 / 4)
    # gijax's set scores the same pixels plus the clamped ones and the sky.
    g = evaluate_batch(jnp.asarray(inv), jnp.asarray(dist), jnp.asarray(valid),
                       jnp.asarray(PAPER_CAND))
    assert g["pixels"] == 12 * 12 - 1 and g["mae"] != pytest.approx(m["mae"])


def test_paper_per_sample_means_and_empty_samples():
    rng = np.random.default_rng(5)
    dist = rng.uniform(0.6, 90.0, (3, 12, 14)).astype(np.float32)
    dist[0, :6] = 1e6                            # fewer pixels in sample 0
    dist[2] = 1e6                                # sample 2: sky only -> no MAE pixel
    inv = (1.0 / dist + rng.normal(0, 0.05, dist.shape)).astype(np.float32)
    inv[2] = rng.uniform(0.01, 0.05, (12, 14))
    valid = np.ones(dist.shape, bool)
    m = _paper(inv, dist, valid)
    ref = _paper_reference(inv, dist, valid, PAPER_CAND)
    for k in ("mae", "rmse", "ssim", "bad_0.1", "bad_0.4"):
        assert m[k] == pytest.approx(ref[k], rel=1e-4, abs=1e-6), k
    assert m["samples"] == 3 and m["pixels"] == 6 * 14 + 12 * 14
    # Mean of per-sample MAEs, not the pooled MAE (the samples have different pixel counts).
    e0 = np.abs(inv[0, 6:] - 1 / dist[0, 6:].astype(np.float64))
    e1 = np.abs(inv[1] - 1 / dist[1].astype(np.float64))
    assert m["mae"] == pytest.approx((e0.mean() + e1.mean()) / 2, rel=1e-5)
    assert m["mae"] != pytest.approx(np.concatenate([e0.ravel(), e1.ravel()]).mean(), rel=1e-3)
    # Batching does not change the result: the values are per sample.
    parts = [jax.tree.map(np.asarray, batch_sums(jnp.asarray(inv[i:i + 1]),
                                                 jnp.asarray(dist[i:i + 1]),
                                                 jnp.asarray(valid[i:i + 1]),
                                                 jnp.asarray(PAPER_CAND), metric_set="paper"))
             for i in range(3)]
    split = summarize({k: np.concatenate([p[k] for p in parts]) for k in parts[0]}, "paper")
    for k in ("mae", "rmse", "ssim"):
        assert split[k] == pytest.approx(m[k], rel=1e-6), k
    only_sky = _paper(inv[2:], dist[2:], valid[2:])
    assert np.isnan(only_sky["mae"]) and np.isfinite(only_sky["ssim"])


def test_paper_ssim_matches_reference_and_is_scale_free():
    rng = np.random.default_rng(1)
    h, w = 20, 36
    yy, xx = np.mgrid[0:h, 0:w]
    a = 0.5 + 0.4 * np.sin(xx / 4.0) * np.cos(yy / 5.0)
    b = a + 0.08 * rng.standard_normal((h, w))
    c = rng.uniform(0.01, 2.0, (h, w))
    x = np.stack([a, b, c]).astype(np.float32)
    y = np.stack([b, c, a]).astype(np.float32)
    got = np.asarray(paper_ssim(jnp.asarray(x), jnp.asarray(y)))
    ref = np.array([_paper_ssim_reference(p, t) for p, t in zip(x, y)])
    np.testing.assert_allclose(got, ref, atol=2e-5)
    assert got[0] < 0.98
    assert float(paper_ssim(jnp.asarray(x[:1]), jnp.asarray(x[:1]))[0]) == pytest.approx(1.0,
                                                                                      abs=1e-5)
    # The data range comes from the images, so 96/d units give the 1/m value.
    got96 = np.asarray(paper_ssim(jnp.asarray(96 * x), jnp.asarray(96 * y)))
    np.testing.assert_allclose(got96, got, atol=2e-5)
    # Unlike gijax's fixed-range, zero-padded SSIM.
    fixed = np.asarray(jnp.mean(ssim_map(jnp.asarray(x), jnp.asarray(y)), axis=(1, 2)))
    assert np.max(np.abs(fixed - got)) > 1e-2
    with pytest.raises(ValueError, match="larger than 10 x 10"):
        paper_ssim(jnp.zeros((1, 10, 30)), jnp.zeros((1, 10, 30)))


@st.composite
def _paper_case(draw):
    shape = draw(st.sampled_from([(1, 12, 16), (2, 14, 20)]))
    seed = draw(st.integers(0, 2 ** 31 - 1))
    rng = np.random.default_rng(seed)
    # Distances spanning both sides of the range, some sky, some near misses at the ends.
    dist = np.exp(rng.uniform(np.log(0.3), np.log(200.0), shape))
    pick = rng.uniform(size=shape)
    dist = np.where(pick < 0.15, 1e6, dist)
    dist = np.where((pick > 0.15) & (pick < 0.2), rng.choice([0.49, 0.5, 100.0, 100.5], shape),
                    dist).astype(np.float32)
    noise = draw(st.floats(0.0, 0.5))
    inv = np.clip(1.0 / dist + noise * rng.standard_normal(shape), 0.01, 2.0).astype(np.float32)
    valid = rng.uniform(size=shape) > draw(st.floats(0.0, 0.3))
    return inv, dist, valid


@settings(max_examples=25, deadline=None)
@given(_paper_case())
def test_paper_metrics_match_reference_property(case):
    inv, dist, valid = case
    m = _paper(inv, dist, valid)
    ref = _paper_reference(inv, dist, valid, PAPER_CAND)
    for k in ("mae", "rmse", "ssim", "bad_0.1", "bad_0.4"):
        if np.isnan(ref[k]):
            assert np.isnan(m[k]), k
        else:
            assert m[k] == pytest.approx(ref[k], rel=1e-4, abs=2e-5), (k, m[k], ref[k])
    assert m["mae"] <= m["rmse"] + 1e-6 or np.isnan(m["mae"])


def test_paper_metrics_differentiable():
    rng = np.random.default_rng(2)
    dist = jnp.asarray(rng.uniform(0.3, 150.0, (1, 12, 12)), jnp.float32)
    inv = jnp.asarray(rng.uniform(0.01, 2.0, (1, 12, 12)), jnp.float32)
    valid = jnp.ones((1, 12, 12), bool)

    def loss(p):
        s = batch_sums(p, dist, valid, jnp.asarray(PAPER_CAND), metric_set="paper")
        return jnp.sum(s["mae"] + s["rmse"] - s["ssim"])

    g = np.asarray(jax.grad(loss)(inv))
    assert np.all(np.isfinite(g)) and np.any(g != 0)


def test_metric_set_errors():
    inv = jnp.ones((1, 12, 12))
    with pytest.raises(ValueError, match="metric_set must be one of"):
        evaluate_batch(inv, inv, inv, PAPER_CAND, metric_set="release")
    sums = jax.tree.map(np.asarray, batch_sums(inv, inv, inv, jnp.asarray(PAPER_CAND)))
    with pytest.raises(ValueError, match="missing"):
        summarize(sums, "paper")


@pytest.mark.parametrize("metric_set", ["paper", "gijax"])
def test_unmatched_pixels_are_lost_coverage_never_nan(metric_set):
    # A 12 x 12 sample whose label is 1 m everywhere (inverse 1), predicted 1.1 except for a
    # block the method could not match: NaN there, and marked unestimated.
    rng = np.random.default_rng(3)
    dist = np.ones((1, 12, 12), np.float32)
    dist[0, :, 6:] = 2.0
    inv = (1.0 / dist + rng.uniform(-0.2, 0.2, dist.shape)).astype(np.float32)
    matched = np.ones((1, 12, 12), bool)
    matched[0, :3, :4] = False
    inv_holes = np.where(matched, inv, np.nan).astype(np.float32)
    m = evaluate_batch(jnp.asarray(inv_holes), jnp.asarray(dist), jnp.ones((1, 12, 12), bool),
                       CAND, metric_set=metric_set, pred_valid=jnp.asarray(matched))
    err = np.abs(inv - 1.0 / dist)[matched]
    assert abs(m["mae"] - err.mean()) < 1e-6
    assert abs(m["rmse"] - np.sqrt((err ** 2).mean())) < 1e-6
    assert abs(m["coverage"] - matched.mean()) < 1e-9 and m["pixels"] == matched.sum()
    # SSIM sees the holes at the far end of the candidate range (1 / 4 m here).
    far = np.where(matched, inv, 0.25).astype(np.float32)
    if metric_set == "gijax":
        want = float(np.mean(_ssim_reference(far[0].astype(np.float64),
                                             (1.0 / dist[0]).astype(np.float64))))
    else:
        want = float(paper_ssim(jnp.asarray(far), jnp.asarray(1.0 / dist))[0])
    assert np.isfinite(m["ssim"]) and abs(m["ssim"] - want) < 2e-4
    # A NaN the method did not flag is treated the same way.
    m2 = evaluate_batch(jnp.asarray(inv_holes), jnp.asarray(dist), jnp.ones((1, 12, 12), bool),
                        CAND, metric_set=metric_set)
    assert all(abs(m2[k] - m[k]) < 1e-6 for k in ("mae", "rmse", "ssim", "coverage"))
