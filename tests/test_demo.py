"""The demo's verdict over several scenes, its argument checks and its figure (no model run)."""

from __future__ import annotations

import numpy as np
import pytest

from gijax.demo import (MethodResult, check_demo_arguments, demo_figure, run_demo,
                        summarize_scenes, verdict, _figure)


def _results(name, maes, seconds=(5.0, 1.0, 3.0)):
    return [MethodResult(name, np.zeros((2, 8)), s, {"mae": m, "rmse": 2 * m, "ssim": 0.5,
                                                     "coverage": 1.0})
            for m, s in zip(maes, seconds)]


def test_a_method_is_summarised_by_its_mean_its_scenes_and_its_later_seconds():
    got = summarize_scenes(_results("net", [0.1, 0.2, 0.6]))
    assert got["mae"] == pytest.approx(0.3) and got["rmse"] == pytest.approx(0.6)
    assert got["mae_per_scene"] == [0.1, 0.2, 0.6]
    # The first call compiles: it is reported apart, the time is the median of the others.
    assert got["first_seconds"] == 5.0 and got["seconds"] == 2.0


def test_the_verdict_counts_scenes_and_compares_means():
    table = {"rig-a": {"net list-1": summarize_scenes(_results("a", [0.10, 0.30, 0.50])),
                       "net list-2": summarize_scenes(_results("b", [0.05, 0.40, 0.30])),
                       "RS-E32": summarize_scenes(_results("c", [0.08, 0.20, 0.40]))}}
    line = verdict(table, "RS-E32")
    # list-2 has the lower mean (0.25 vs 0.30); it beats the baseline on scenes 1 and 3; the
    # baseline's mean 0.2267 is lower still.
    assert line == ("verdict: rig-a: RS-E32 ahead on mean MAE (net list-2 0.2500 vs RS-E32 "
                    "0.2267); the learned model wins 2 of 3 scenes")


@pytest.mark.parametrize("kw, message", [
    ({"baseline": "RS-E33"}, "--baseline 'RS-E33' is not a classical baseline; expected one of"),
    ({"rigs": ("paper-train", "ring9")}, "demo rigs ['ring9'] are not built in"),
    ({"scenes": 0}, "--scenes must be 1-64; found 0"),
])
def test_bad_arguments_fail_before_any_work_and_leave_no_folder(tmp_path, kw, message):
    out = tmp_path / "demo"
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        run_demo(out, **kw)
    assert not out.exists()


def test_a_model_that_does_not_exist_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="no-such-model"):
        check_demo_arguments(tmp_path / "d", tmp_path / "no-such-model", "RS-E32",
                             ("paper-train",), 3)


def test_the_figure_keeps_the_panorama_aspect_and_marks_missing_pixels(tmp_path):
    import cv2

    rng = np.random.default_rng(0)
    distance = rng.uniform(1.0, 5.0, (16, 64)).astype(np.float32)
    distance[0, :8] = np.nan                      # no label there
    sample = {"pano_distance": distance,
              "images": rng.integers(0, 80, (3, 32, 32, 3), dtype=np.uint8),
              "masks": np.ones((3, 32, 32), np.uint8)}
    guess = 1.0 / distance
    guess[5:9, 20:30] = np.nan                    # no estimate there
    methods = [MethodResult("net", guess, 1.0, {"mae": 0.01}),
               MethodResult("RS-E32", guess * 1.1, 1.0, {"mae": 0.02})]
    import matplotlib.pyplot as plt

    fig = demo_figure([("paper-train", sample, methods)], 3)
    try:
        fig.canvas.draw()
        panoramas = [ax for sub in fig.subfigs for ax in sub.axes
                     if ax.images and ax.images[0].get_array().shape == (16, 64)]
        assert len(panoramas) == 1 + 2 + 2            # truth, two methods and their errors
        for ax in panoramas:
            box = ax.get_window_extent()
            assert box.width / box.height == pytest.approx(4.0, rel=0.03)
            bad = ax.images[0].cmap.get_bad()
            assert tuple(bad[:3]) in ((0.0, 0.0, 0.0), (0.6, 0.6, 0.6))   # never white
        truth = panoramas[0].images[0]
        assert np.ma.getmaskarray(truth.get_array())[0, :8].all()     # drawn in the bad colour
        # Ground truth and predictions share the colour scale taken from the labels.
        limits = {ax.images[0].get_clim() for ax in panoramas if "error" not in ax.get_title()}
        assert len(limits) == 1
        assert limits.pop()[1] == pytest.approx(np.nanpercentile(1.0 / distance, 99), rel=1e-6)
    finally:
        plt.close(fig)
    path = tmp_path / "demo.png"
    _figure(path, [("paper-train", sample, methods)], 3)
    assert cv2.imread(str(path)) is not None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.png"]


def test_every_method_gets_the_calibrated_rig_and_the_images_at_the_models_size(
        tmp_path, monkeypatch, capsys):
    """Predictors take a rig at its calibrated size and scale the images to the model's size
    from it; the demo renders at the model's size, so it must hand over the calibrated rig (a
    rig already scaled would have the learned model's images scaled a second time). The
    rendering and the methods are stand-ins that record what they are given."""
    import gijax.demo as demo
    import gijax.render
    from gijax.geometry.layouts import builtin_rig
    from gijax.model import model_panorama
    from gijax.store import load_model

    _, config, _ = load_model(demo.DEFAULT_MODEL)
    pano = model_panorama(config)
    rendered_for, given = [], []

    def fake_render(rig, seed, pano):
        rendered_for.append(rig)
        n, h, w = rig.num_cameras, rig.cameras[0].height, rig.cameras[0].width
        rng = np.random.default_rng(seed)
        return {"images": rng.integers(0, 255, (n, h, w, 3), np.uint8),
                "masks": np.ones((n, h, w), np.uint8),
                "pano_distance": np.full((pano.height, pano.width), 3.0, np.float32)}

    def fake_evaluate(predictor, rig, sample, candidates):
        given.append((type(predictor).__name__, rig, sample["images"].shape))
        inv = np.full((pano.height, pano.width), 1 / 3, np.float32)
        res = {"distance": np.full(inv.shape, 3.0, np.float32), "valid": np.ones(inv.shape, bool),
               "colour": np.zeros(inv.shape + (3,), np.float32)}
        return inv, 0.1, {"mae": 0.01, "rmse": 0.02, "ssim": 0.9, "coverage": 1.0}, res

    monkeypatch.setattr(gijax.render, "render_sample", fake_render)
    monkeypatch.setattr(demo, "_evaluate", fake_evaluate)
    run_demo(tmp_path / "demo", seed=3, scenes=1, progress=False)

    assert len(given) == 2 * 4                   # 2 rigs x (3 candidate lists + the baseline)
    for name, made in zip(demo.DEMO_RIGS, rendered_for):
        calibrated = builtin_rig(name)
        assert made.cameras[0].width == round(calibrated.cameras[0].width * config.image_scale)
        for kind, rig, shape in [g for g in given if g[1].num_cameras == calibrated.num_cameras]:
            assert rig.cameras[0].width == calibrated.cameras[0].width, kind
            assert shape[2] == made.cameras[0].width, kind
    assert {kind for kind, _, _ in given} == {"LearnedPredictor", "RtssPredictor"}
    # A bundled model is called by its bundle name (two bundles may share a preset), and the
    # printed table stays in columns however long the names.
    import json

    methods = json.loads((tmp_path / "demo" / "demo.json").read_text())["table"]["paper-train"]
    assert f"{demo.DEFAULT_MODEL} paper's GI at camera spacing" in methods
    lines = capsys.readouterr().out.splitlines()
    header = next(line for line in lines if line.startswith("rig "))
    end = header.index(" MAE") + 4
    rows = [line for line in lines if line.startswith(demo.DEMO_RIGS)]
    assert len(rows) == 8 and all(row[end - 7:end] == " 0.0100" for row in rows), rows
    assert demo.model_title(tmp_path, "E8-cpu") == "E8-cpu"     # a run folder: its preset
