"""The paper-table experiments: both scripts end to end at the smoke scale, resume, claims, metrics.

The smoke scale checks the pipeline (data -> training -> evaluation -> tables, figures and
claims), not the paper's claims: its models are tiny and barely trained.
"""

import json
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

# The experiment scripts live beside the package, not in it.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments import claims, evaluation, reporting, scales, workfolder  # noqa: E402
from experiments import new_layout, same_layout  # noqa: E402

PROVENANCE_FIELDS = ("command", "seed", "git_revision", "durations_s", "machine", "scale",
                     "datasets", "data_seeds")


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    """Both scripts at --scale smoke in one work folder, then both again (the resume)."""
    root = tmp_path_factory.mktemp("experiments")
    work = root / "work"
    outs = {"same": root / "out" / "same", "new": root / "out" / "new"}
    mods = {"same": same_layout, "new": new_layout}
    seconds, docs, snapshots = {}, {}, {}
    for rnd in ("first", "second"):
        for name in ("same", "new"):
            t0 = time.perf_counter()
            rc = mods[name].main(["--scale", "smoke", "--work", str(work),
                                  "--out", str(outs[name])])
            assert rc == 0
            seconds[(rnd, name)] = time.perf_counter() - t0
            docs[(rnd, name)] = json.loads(outs[name].with_suffix(".json").read_text())
        snapshots[rnd] = {str(p.relative_to(work / "runs")): p.stat().st_mtime_ns
                          for p in sorted((work / "runs").rglob("*")) if p.is_file()}
    print("smoke wall seconds:", {f"{a}/{b}": round(s, 1) for (a, b), s in seconds.items()})
    return {"work": work, "outs": outs, "docs": docs, "seconds": seconds,
            "snapshots": snapshots}


def _check_metrics(row):
    for key in ("mae", "rmse", "ssim", "coverage", "time_ms", "peak_mb"):
        assert row[key] is not None and math.isfinite(row[key]), (row["model"], key, row[key])
    # Inverse distance lies in [0.01, 2] 1/m, so errors cannot exceed 2; RMSE >= MAE.
    assert 0.0 < row["mae"] <= row["rmse"] <= 2.0
    assert -1.0 <= row["ssim"] <= 1.0
    assert 0.0 < row["coverage"] <= 1.0
    assert row["time_ms"] > 0 and row["peak_mb"] > 0
    assert row["samples"] == 2


@pytest.mark.slow
def test_same_layout_table(smoke):
    doc = smoke["docs"][("first", "same")]
    assert [r["model"] for r in doc["rows"]] == ["RS-E16", "G16VV"]
    for r in doc["rows"]:
        _check_metrics(r)
    g16vv = doc["rows"][1]
    assert g16vv["kind"] == "learned" and g16vv["preset"] == "G16VV-cpu"
    # Validated during training, so the evaluation loaded the best validated checkpoint.
    assert doc["training"]["G16VV"]["validation"]["samples"] == 2
    assert (smoke["work"] / "runs" / "G16VV-cpu" / "best").is_dir()
    assert len(g16vv["candidates"]) == 16 and np.all(np.diff(g16vv["candidates"]) > 0)
    md = smoke["outs"]["same"].with_suffix(".md").read_text()
    for name in ("RS-E16", "G16VV-cpu", "## Claims", "## Provenance", "git revision"):
        assert name in md
    assert [c["status"] for c in doc["claims"]][0] == "N/A"      # no E8 / G8 at this scale
    assert doc["claims"][1]["status"] in ("PASS", "FAIL")
    img = cv2.imread(str(smoke["outs"]["same"].with_suffix(".png")))
    assert img is not None and img.shape[0] > 200 and img.shape[1] > 400


@pytest.mark.slow
def test_new_layout_table(smoke):
    doc = smoke["docs"][("first", "new")]
    keys = [(r["layout"], r["model"], r["eval_candidates"]) for r in doc["rows"]]
    assert keys == [(layout, *k) for layout in ("paper-test2", "paper-test3", "paper-train-1m")
                    for k in (("RS-E16", "ev"), ("G16VV", "train"), ("G16VV", "spacing"),
                              ("G16VV", "rig"))]
    for r in doc["rows"]:
        _check_metrics(r)
    by = {k: r for k, r in zip(keys, doc["rows"])}
    for layout in ("paper-test2", "paper-test3", "paper-train-1m"):
        # The paper's recomputed list is the closed form at the 1 m spacing of all three
        # layouts; gijax's rig-aware list differs from the training list, same range.
        np.testing.assert_allclose(by[(layout, "G16VV", "spacing")]["candidates"],
                                   closed_form_at_1m(), rtol=1e-6)
        train = np.array(by[(layout, "G16VV", "train")]["candidates"])
        new = np.array(by[(layout, "G16VV", "rig")]["candidates"])
        assert train.shape == new.shape == (16,)
        assert not np.allclose(train, new)
        assert new[0] == pytest.approx(0.5) and new[-1] == pytest.approx(100.0)
        assert by[(layout, "G16VV", "spacing")]["metric_set"] == "paper"
        assert by[(layout, "G16VV", "spacing")]["mae_gijax"] > 0
    assert by[("paper-test3", "G16VV", "train")]["cameras"] == 4
    assert [c["claim"][:3] for c in doc["claims"]] == ["(b)", "(b,", "(c)"]
    assert "camera spacing" in doc["claims"][0]["claim"]
    assert doc["claims"][1]["claim"].startswith("(b, rig)")
    for claim in doc["claims"][:2]:
        assert set(claim["numbers"]) == {"paper-test2/G16VV", "paper-test3/G16VV"}
    # What the rig-aware rule gives: on the training rig an EV-like list, not the released G16
    # (which is the paper's list there).
    rig_aware = {s["rig"]: s for s in doc["rig_aware_lists"]}
    assert set(rig_aware) == {"paper-train", "paper-test2", "paper-test3", "paper-train-1m"}
    train_rig = rig_aware["paper-train"]
    assert train_rig["camera_spacing_m"] == pytest.approx(0.3095, abs=1e-3)
    assert train_rig["max_rel_dev_from_ev"] < 0.05 < train_rig["max_rel_dev_from_paper"]
    assert rig_aware["paper-test2"]["camera_spacing_m"] == pytest.approx(1.0, abs=1e-3)
    # Step table: the rig-aware list has equal mean steps by construction, and a wider rig
    # moves features further per step than the training rig with the same list.
    steps = {(s["rig"], s["list"]): s for s in doc["candidate_steps"]}
    assert set(steps) == {("paper-train", "training GI16")} | {
        (layout, name) for layout in ("paper-test2", "paper-test3", "paper-train-1m")
        for name in ("training GI16", "rig (16)", "spacing (16)")}
    for layout in ("paper-test2", "paper-test3", "paper-train-1m"):
        # The list was solved in float32, the steps are measured in float64.
        assert steps[(layout, "rig (16)")]["min_max_ratio"] == pytest.approx(1.0, abs=1e-4)
        assert (steps[(layout, "training GI16")]["mean_px"]
                > 1.2 * steps[("paper-train", "training GI16")]["mean_px"])
    for layout in ("paper-test2", "paper-test3", "paper-train-1m"):
        png = smoke["outs"]["new"].with_name(f"new_{layout}.png")
        assert cv2.imread(str(png)) is not None


def closed_form_at_1m():
    """The paper's closed form at b = 1 m, n = 16, 0.5..100 m, written out in NumPy."""
    theta = np.linspace(np.arctan(1.0 / 0.5), np.arctan(1.0 / 100.0), 16)
    return 1.0 / np.tan(theta)


@pytest.mark.slow
def test_provenance(smoke):
    for name in ("same", "new"):
        prov = smoke["docs"][("first", name)]["provenance"]
        for field in PROVENANCE_FIELDS:
            assert field in prov, field
        assert prov["command"].startswith(f"python experiments/{name}_layout.py --scale smoke")
        assert prov["seed"] == 0 and prov["scale"] == "smoke"
        assert prov["machine"]["cpu_count"] >= 1 and prov["machine"]["versions"]["jax"]
        assert prov["machine"]["platform"]
        assert len(prov["git_revision"]) >= 7
        assert prov["durations_s"]["total"] > 0
        # Held-out test scenes: a different dataset seed from the training data.
        seeds = {d["role"]: d["seed"] for d in prov["datasets"]}
        assert all(seeds[t] != seeds["train"] for t in seeds if t.startswith("paper-test"))


@pytest.mark.slow
def test_rerun_reuses_everything(smoke):
    first, second = smoke["snapshots"]["first"], smoke["snapshots"]["second"]
    assert first == second, "the second run rewrote files of a finished training"
    for name in ("same", "new"):
        doc = smoke["docs"][("second", name)]
        assert all(r["reused"] for r in doc["training"].values())
        assert all(r["reused"] for r in doc["rows"] if r["status"] == "ok")
        # Identical metrics: nothing was recomputed.
        before = smoke["docs"][("first", name)]["rows"]
        assert [r["mae"] for r in doc["rows"]] == [r["mae"] for r in before]


@pytest.mark.slow
def test_held_out_check_rejects_shared_seeds(smoke):
    assert workfolder.check_held_out(smoke["work"], ["paper-test1"]) == {"paper-test1": 0}
    with pytest.raises(ValueError, match="shares scene seeds"):
        workfolder.check_held_out(smoke["work"], ["train"])


# --------------------------------------------------------------------------- pieces


class _Reader:
    def __init__(self, samples):
        self.samples = samples
        self.root = "memory"

    def __len__(self):
        return len(self.samples)

    def __getitem__(self, i):
        return self.samples[i]


def test_evaluate_matches_numpy_reference():
    rng = np.random.default_rng(3)
    cand = np.geomspace(0.5, 100.0, 8)
    samples, preds, ests = [], [], []
    for _ in range(2):
        dist = rng.uniform(0.3, 150.0, (12, 16)).astype(np.float32)
        dist[0, :3] = 1e6                      # sky: excluded (paper), clamped (gijax)
        dist[1, 0] = np.nan                    # unusable label
        samples.append({"images": None, "masks": None, "pano_distance": dist})
        preds.append(rng.uniform(0.0, 2.0, (12, 16)).astype(np.float32))
        est = rng.uniform(size=(12, 16)) > 0.2
        ests.append(est)
    calls = iter(zip(preds, ests))
    metrics, first = evaluation.evaluate(
        _Reader(samples), evaluation.Predictor(lambda im, m: next(calls), cand, 1.0))
    errs, paper_mae, paper_rmse, est_count, lab_count = [], [], [], 0, 0
    for s, p, e in zip(samples, preds, ests):
        d = s["pano_distance"].astype(np.float64)
        lab = np.isfinite(d) & (d > 0)
        target = np.clip(1.0 / np.where(lab, d, 100.0), 1 / 100.0, 1 / 0.5)
        use = lab & e
        errs.append((p - target)[use])
        inside = use & (d >= 0.5) & (d <= 100.0)
        e_in = p[inside] - 1.0 / d[inside]
        paper_mae.append(np.abs(e_in).mean())
        paper_rmse.append(np.sqrt((e_in ** 2).mean()))
        est_count += use.sum()
        lab_count += lab.sum()
    errs = np.concatenate(errs)
    # The paper's columns: per-sample values over in-range labels, averaged over samples.
    assert metrics["metric_set"] == "paper"
    assert metrics["mae"] == pytest.approx(np.mean(paper_mae), rel=1e-5)
    assert metrics["rmse"] == pytest.approx(np.mean(paper_rmse), rel=1e-5)
    # gijax's beside them: clamped labels pooled over all estimated pixels.
    assert metrics["mae_gijax"] == pytest.approx(np.abs(errs).mean(), rel=1e-5)
    assert metrics["rmse_gijax"] == pytest.approx(np.sqrt((errs ** 2).mean()), rel=1e-5)
    assert metrics["pixels_gijax"] == est_count > metrics["pixels"]
    assert metrics["coverage"] == pytest.approx(est_count / lab_count)
    assert metrics["samples"] == 2
    np.testing.assert_array_equal(np.isnan(first), ~ests[0])


def _rows(**mae):
    return [{"model": m, "kind": "classical" if m.startswith("RS") else "learned",
             "status": "ok", "mae": v} for m, v in mae.items()]


def test_claim_a_and_c_verdicts():
    assert claims.claim_gi_at_least_ev(_rows(E8=0.02, G8=0.02))["status"] == "PASS"
    fail = claims.claim_gi_at_least_ev(_rows(E8=0.020, G8=0.025))
    assert fail["status"] == "FAIL" and fail["numbers"] == {"G8": 0.025, "E8": 0.020}
    assert "-25.0 %" in fail["detail"]
    assert claims.claim_gi_at_least_ev(_rows(E8=0.02))["status"] == "N/A"
    c = claims.claim_learned_beats_classical(_rows(**{"RS-E16": 0.10, "RS-E32": 0.08, "E8": 0.05,
                                                 "G8": 0.06}))
    assert c["status"] == "PASS" and c["numbers"]["all"]["ratio"] == pytest.approx(0.06 / 0.08)
    c = claims.claim_learned_beats_classical(_rows(**{"RS-E32": 0.08, "G8": 0.061}))
    assert c["status"] == "FAIL"                     # 0.7625 > 0.75: not clearly better


def test_claim_b_pairs_and_reductions():
    rows = [{"layout": "paper-test2", "model": "G16", "kind": "learned", "status": "ok",
             "eval_candidates": "train", "mae": 0.030},
            {"layout": "paper-test2", "model": "G16", "kind": "learned", "status": "ok",
             "eval_candidates": "spacing", "mae": 0.020},
            {"layout": "paper-test3", "model": "E16", "kind": "learned", "status": "n/a",
             "eval_candidates": "-", "mae": None},
            {"layout": "paper-test3", "model": "G16VV", "kind": "learned", "status": "ok",
             "eval_candidates": "train", "mae": 0.024},
            {"layout": "paper-test3", "model": "G16VV", "kind": "learned", "status": "ok",
             "eval_candidates": "spacing", "mae": 0.016}]
    b = claims.claim_recomputed_candidates(rows)
    assert b["status"] == "PASS" and b["claim"].startswith("(b) the paper's")
    assert b["numbers"]["paper-test2/G16"]["reduction_percent"] == pytest.approx(100 / 3)
    assert b["numbers"]["paper-test3/G16VV"]["reduction_percent"] == pytest.approx(100 / 3)
    rows[1]["mae"] = 0.031
    assert claims.claim_recomputed_candidates(rows)["status"] == "FAIL"
    # Rows outside the scope are reported but do not decide the verdict.
    scoped = claims.claim_recomputed_candidates(rows, lambda r: r["model"] != "G16")
    assert scoped["status"] == "PASS" and "beside the paper's scope: G16" in scoped["detail"]
    assert scoped["numbers"]["paper-test2/G16"]["in_scope"] is False
    # The same check for gijax's rig-aware list pairs its own rows with the training list.
    rows.append({"layout": "paper-test2", "model": "G16", "kind": "learned", "status": "ok",
                 "eval_candidates": "rig", "mae": 0.015})
    rig = claims.claim_recomputed_candidates(rows, new="rig")
    assert rig["status"] == "PASS" and rig["claim"].startswith("(b, rig)")
    assert rig["numbers"]["paper-test2/G16"]["reduction_percent"] == pytest.approx(50.0)
    assert "paper-test3/G16VV" not in rig["numbers"]          # no rig-aware row there


def test_concat_models_cannot_take_four_cameras():
    from gijax.nn.presets import get_preset

    assert "exactly 3 cameras" in new_layout.unsupported(get_preset("E16-cpu"), 4)
    assert new_layout.unsupported(get_preset("E16-cpu"), 3) is None
    assert new_layout.unsupported(get_preset("G16VV-cpu"), 4) is None


def test_results_section_update(tmp_path):
    md = tmp_path / "RESULTS.md"
    md.write_text("# R\n\n<!-- t:begin -->\nold\n<!-- t:end -->\n\nkept\n")
    reporting.update_results_section(md, "t", "new table")
    assert md.read_text() == "# R\n\n<!-- t:begin -->\nnew table\n<!-- t:end -->\n\nkept\n"
    with pytest.raises(ValueError, match="markers"):
        reporting.update_results_section(md, "other", "x")


def test_scales_are_consistent():
    from gijax.nn.presets import get_preset

    for scale in scales.SCALES.values():
        assert set(scale.test_samples) == set(scales.TEST_RIGS)
        for model in scale.models:
            mc = get_preset(scales.preset_name(scale, model))
            if not scale.tiny:
                # The label panorama is the network's output.
                assert tuple(mc.output_hw) == tuple(scale.pano_hw)
                assert mc.image_scale == scale.image_scale
    assert scales.SCALES["cpu"].models == scales.MODELS
    assert scales.SCALES["smoke"].steps < 10
