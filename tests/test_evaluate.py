"""gijax.evaluate: the usable-label rule, the evaluation loop against hand-computed metrics,
and the learned model and the classical baseline scored through the same loop."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gijax.evaluate import (Prediction, Predictor, evaluate_predictions, label_mask,
                            usable_label)
from gijax.geometry.layouts import builtin_rig
from gijax.geometry.rig import scale_rig

CAND = np.geomspace(0.5, 100.0, 8)


def test_usable_label_against_a_closed_form_array():
    d = np.array([np.nan, np.inf, -np.inf, -1.0, 0.0, 1e-9, 0.3, 2.0, 1e6], np.float32)
    expected = np.array([0, 0, 0, 0, 0, 1, 1, 1, 1], bool)
    got = usable_label(d)
    assert isinstance(got, np.ndarray)                 # host arrays stay on the host
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(np.asarray(usable_label(jnp.asarray(d))), expected)
    valid = np.array([1, 1, 1, 1, 1, 0, 1, 1, 0], bool)
    np.testing.assert_array_equal(np.asarray(label_mask(jnp.asarray(d), jnp.asarray(valid))),
                                  (expected & valid).astype(np.float32))


def _tiny_case():
    """Three 12 x 12 samples in batches of 2 and 1: labels with sky, unusable and out-of-range
    pixels; predictions with holes."""
    rng = np.random.default_rng(7)
    dist = rng.uniform(0.3, 150.0, (3, 12, 12)).astype(np.float32)
    dist[0, 0, :3] = [1e6, np.nan, -2.0]
    inv = rng.uniform(0.0, 2.0, (3, 12, 12)).astype(np.float32)
    est = rng.uniform(size=(3, 12, 12)) > 0.15
    inv[2, 5, 5] = np.nan                               # a non-finite estimate is a hole too
    return dist, inv, est


def test_loop_matches_hand_computed_mae_and_rmse():
    dist, inv, est = _tiny_case()
    batches = [{"distance": dist[:2], "at": slice(0, 2)}, {"distance": dist[2:], "at": slice(2, 3)}]
    result = evaluate_predictions(
        batches, lambda b: Prediction(inv_distance=inv[b["at"]], valid=est[b["at"]]), CAND,
        metric_sets=("paper", "gijax"))
    d = dist.astype(np.float64)
    lab = np.isfinite(d) & (d > 0)
    have = est & np.isfinite(inv)
    use = lab & have
    # gijax: the label clamped to 0.01 .. 2 1/m, errors pooled over every scored pixel.
    target = np.clip(1.0 / np.where(lab, d, 100.0), 0.01, 2.0)
    err = (inv - target)[use]
    g = result.metrics["gijax"]
    assert g["mae"] == pytest.approx(np.abs(err).mean(), rel=1e-5)
    assert g["rmse"] == pytest.approx(np.sqrt((err ** 2).mean()), rel=1e-5)
    assert g["pixels"] == use.sum() and g["coverage"] == pytest.approx(use.sum() / lab.sum())
    # paper: per sample over labels inside 0.5 .. 100 m, then the mean over samples.
    inside = use & (d >= 0.5) & (d <= 100.0)
    maes = [np.abs(inv[i] - 1.0 / d[i])[inside[i]].mean() for i in range(3)]
    rmses = [np.sqrt(((inv[i] - 1.0 / d[i])[inside[i]] ** 2).mean()) for i in range(3)]
    p = result.metrics["paper"]
    assert p["mae"] == pytest.approx(np.mean(maes), rel=1e-5)
    assert p["rmse"] == pytest.approx(np.mean(rmses), rel=1e-5)
    assert p["samples"] == 3 == result.samples
    np.testing.assert_allclose([s["mae"] for s in result.per_scene("paper")], maes, rtol=1e-5)
    assert result.label_coverage == pytest.approx(use.sum() / lab.sum())
    assert len(result.seconds) == 2


def test_holes_choices_change_only_ssim_and_limit_stops_early():
    dist, inv, est = _tiny_case()

    def run(holes, limit=0):
        return evaluate_predictions(
            [{"distance": dist[i:i + 1], "i": i} for i in range(3)],
            lambda b: Prediction(inv_distance=inv[b["i"]][None], valid=est[b["i"]][None]),
            CAND, holes=holes, limit=limit).metrics["paper"]

    far, unscored = run("far"), run("unscored_far")
    assert unscored["mae"] == pytest.approx(far["mae"], rel=1e-6)
    assert unscored["rmse"] == pytest.approx(far["rmse"], rel=1e-6)
    assert unscored["ssim"] != far["ssim"]
    assert run("far", limit=2)["samples"] == 2
    with pytest.raises(ValueError, match="holes must be one of"):
        run("zero")
    with pytest.raises(ValueError, match="no data yielded no samples"):
        evaluate_predictions([], None, CAND, name="no data")


@pytest.mark.usefixtures("quick_compiles")
def test_learned_and_rtss_through_the_same_loop_on_a_rendered_sample():
    from gijax.evaluate.metrics import evaluate_batch
    from gijax.model import create_model, model_panorama
    from gijax.predict import LearnedPredictor, RtssPredictor
    from gijax.render import render_fronto_plane

    from test_predict import G8, TINY

    pano = model_panorama(TINY)
    rig = scale_rig(builtin_rig("paper-train"), TINY.image_scale)
    sample = render_fronto_plane(rig, 2.2, seed=4, pano=pano)   # a sphere 2.2 m around the rig
    predictors = {"learned": LearnedPredictor(create_model(TINY, seed=0), G8, pano),
                  "rtss": RtssPredictor("RS-E16", np.asarray(G8), pano, colours=False)}
    preds = {}
    for name, predictor in predictors.items():
        kept = {}

        def run(_batch):
            # The calibrated rig, as a user calls it: the images are read at their own size.
            pred = predictor.predict(builtin_rig("paper-train"), sample["images"],
                                     sample["masks"])
            kept["pred"] = pred
            return pred.replace(inv_distance=pred.inv_distance[None], valid=pred.valid[None])

        result = evaluate_predictions([{"distance": sample["pano_distance"][None]}], run, G8)
        pred = preds[name] = kept["pred"]
        assert isinstance(predictor, Predictor) and isinstance(pred, Prediction), name
        assert pred.inv_distance.shape == pano.shape == pred.valid.shape, name
        assert np.all(np.isfinite(pred.inv_distance[pred.valid])), name
        # The metrics the loop reports are those of the prediction it was handed.
        direct = evaluate_batch(jnp.asarray(pred.inv_distance[None]),
                                jnp.asarray(sample["pano_distance"][None]),
                                jnp.asarray(usable_label(sample["pano_distance"])[None]), G8,
                                metric_set="paper", pred_valid=jnp.asarray(pred.valid[None]))
        for key in ("mae", "rmse", "ssim", "coverage"):
            assert result.metrics["paper"][key] == pytest.approx(direct[key], rel=1e-6), (name,
                                                                                         key)
        assert 0 < result.metrics["paper"]["mae"] < 2.0, name
    # One result type; the learned model's candidate distribution is in its result, the
    # baseline (winner-take-all) has none.
    assert {"inv_distance", "distance", "valid", "entropy", "prob", "colour", "rgb",
            "rgb_valid", "candidates", "panorama"} == set(preds["learned"])
    assert {"inv_distance", "distance", "valid", "candidates", "panorama"} == set(preds["rtss"])
    assert preds["rtss"].get("entropy") is None


@pytest.mark.usefixtures("quick_compiles")
def test_raw_image_batch_predictors_agree_with_the_one_sample_edge():
    """The batch predictors of raw images (what the experiments time) on two renders: the
    learned one gives a sample what ``predict`` gives it (from the calibrated rig, as a user
    calls it; the same compiled program) and keeps the samples of a batch apart, the baseline
    finds the rendered sphere's distance, and both lower to a program with a memory
    analysis."""
    from flax import nnx

    from gijax.baseline.rtss import get_rtss_preset
    from gijax.model import create_model, model_panorama
    from gijax.predict import LearnedImagePredictor, RtssBatchPredictor, predict
    from gijax.render import render_fronto_plane

    from test_predict import G8, TINY

    pano = model_panorama(TINY)
    calibrated = builtin_rig("paper-train")
    rig = scale_rig(calibrated, TINY.image_scale)          # the model's image size
    samples = [render_fronto_plane(rig, 2.2, seed=s, pano=pano) for s in (4, 5)]
    batch = {"images": np.stack([s["images"] for s in samples]),
             "masks": np.stack([s["masks"] for s in samples]).astype(np.float32)}
    model = create_model(TINY, seed=0)
    # Larger weights than the initialisation's, so the untrained network's inverse distance
    # spans the candidate range instead of sitting at one value: a wrong input would show.
    nnx.update(model, jax.tree.map(lambda x: 2.0 * x, nnx.state(model, nnx.Param)))
    learned = LearnedImagePredictor(model, rig, G8, pano)
    for i, s in enumerate(samples):
        one = learned({k: v[i:i + 1] for k, v in batch.items()})
        alone = predict(model, calibrated, s["images"], s["masks"], G8, pano=pano,
                        colours=False).inv_distance
        assert np.ptp(alone) > 0.5 and bool(np.all(one.valid))
        np.testing.assert_array_equal(np.asarray(one.inv_distance[0]), alone)
    # In a batch each sample is its own: swapping them swaps the maps.
    got = np.asarray(learned(batch).inv_distance)
    swapped = np.asarray(learned({k: v[::-1] for k, v in batch.items()}).inv_distance)
    assert got.shape == (2, *pano.shape) and not np.array_equal(got[0], got[1])
    np.testing.assert_array_equal(got, swapped[::-1])
    config = get_rtss_preset("RS-E16")
    config = config.replace(match_size=min(config.match_size, rig.cameras[0].width))
    rtss = RtssBatchPredictor(rig, G8, pano, config)
    out = rtss(batch)
    inv, valid = np.asarray(out.inv_distance), np.asarray(out.valid)
    assert inv.shape == valid.shape == (2, *pano.shape) and valid.mean() > 0.5
    # Near the sphere's 1/2.2 m on most estimated pixels: closer than half the inverse gap
    # between the candidates around it (1.91 and 3.77 m, 0.26 1/m apart).
    assert np.median(np.abs(inv[valid] - 1 / 2.2)) < 0.1
    for predictor in (learned, rtss):
        assert predictor.lower(batch).compile().memory_analysis() is not None
