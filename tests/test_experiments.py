"""The experiments: the paper-table scripts and the learned-candidates script end to end at the
smoke scale, resume, claims, metrics.

The smoke scale checks the pipeline (data -> training -> evaluation -> tables, figures and
claims), not the paper's claims: its models are tiny and barely trained.
"""

import json
import math
import sys
import time
from pathlib import Path

import cv2
import jax
import numpy as np
import pytest

# The experiment scripts live beside the package, not in it.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments import claims, evaluation, reporting, scales, workfolder  # noqa: E402
from experiments import learned_candidates, new_layout, same_layout  # noqa: E402

PROVENANCE_FIELDS = ("command", "seed", "git_revision", "durations_s", "machine", "scale",
                     "datasets", "data_seeds")


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    """Both scripts at --scale smoke in one work folder, then both again (the resume). XLA's
    optimisation passes are off for the scripts (not for the rendering of their data), as for
    the learned-candidates fixture below: the smoke checks
    (files, reuse, metrics against their numpy reference, claims logic) do not depend on them,
    and they dominate the compile time of the renders, trainings and evaluations."""
    root = tmp_path_factory.mktemp("experiments")
    work = root / "work"
    outs = {"same": root / "out" / "same", "new": root / "out" / "new"}
    mods = {"same": same_layout, "new": new_layout}
    seconds, docs, snapshots = {}, {}, {}
    # The datasets of all three scripts are rendered first, with XLA's optimisations: the
    # renderer runs about 4x slower unoptimised, and the scripts then find them complete.
    scale = scales.SCALES["smoke"]
    same_layout.prepare(scale, work, ["paper-train-1m"], {})
    learned_candidates.prepare(scale, learned_candidates.SIZES["smoke"], work, {"data": 0.0})
    previous = jax.config.read("jax_disable_most_optimizations")
    jax.config.update("jax_disable_most_optimizations", True)
    try:
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
    finally:
        jax.config.update("jax_disable_most_optimizations", previous)
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


@pytest.fixture(scope="module")
def learned(smoke):
    """learned_candidates.py at --scale smoke in the smoke work folder (its G16VV run, datasets
    and cached evaluations reused), then again (the resume). XLA's optimisation passes are off
    for it, as in conftest's ``quick_compiles``: these checks do not depend on them and they
    dominate the compile time of its trainings and adaptations."""
    out = smoke["work"].parent / "out" / "learned"
    argv = ["--scale", "smoke", "--work", str(smoke["work"]), "--out", str(out)]
    docs, seconds = {}, {}
    previous = jax.config.read("jax_disable_most_optimizations")
    jax.config.update("jax_disable_most_optimizations", True)
    try:
        for rnd in ("first", "second"):
            t0 = time.perf_counter()
            assert learned_candidates.main(argv) == 0
            seconds[rnd] = time.perf_counter() - t0
            docs[rnd] = json.loads(out.with_suffix(".json").read_text())
    finally:
        jax.config.update("jax_disable_most_optimizations", previous)
    print("learned_candidates smoke wall seconds:", {k: round(v, 1) for k, v in seconds.items()})
    return {"out": out, "docs": docs, "seconds": seconds}


LISTS_NEW_RIG = [("fixed list", lst) for lst in ("train", "spacing", "rig", "supervised",
                                                  "photometric")] + [("learned list", "learned")]


@pytest.mark.slow
def test_learned_candidates_table(learned, smoke):
    doc = learned["docs"]["first"]
    keys = [(r["layout"], r["training"], r["list"]) for r in doc["rows"]]
    assert keys == ([("paper-test1", "fixed list", "train"), ("paper-test1", "learned list",
                                                              "learned")]
                    + [(rig, *k) for rig in ("paper-test2", "paper-test3", "ring5-0.5m")
                       for k in LISTS_NEW_RIG])
    for r in doc["rows"]:
        _check_metrics({**r, "model": f"{r['layout']}/{r['list']}"})
    by = dict(zip(keys, doc["rows"]))
    # The fixed-list model is same_layout's run, and its training, 'spacing' and 'rig'
    # evaluations are the ones same_layout.py and new_layout.py cached.
    fixed = doc["training"]["fixed list"]
    assert fixed["reused"] and fixed["command"] == \
        smoke["docs"][("first", "same")]["training"]["G16VV"]["command"]
    new = {(r["layout"], r["eval_candidates"]): r["mae"]
           for r in smoke["docs"][("first", "new")]["rows"] if r["model"] == "G16VV"}
    for rig in ("paper-test2", "paper-test3"):
        for spec in ("train", "spacing", "rig"):
            assert by[(rig, "fixed list", spec)]["reused"]
            assert by[(rig, "fixed list", spec)]["mae"] == new[(rig, spec)]
    assert by[("paper-test1", "fixed list", "train")]["reused"]
    # The learned-list training is the fixed one's command with the list learned.
    learned_run = doc["training"]["learned list"]
    assert not learned_run["reused"] and learned_run["steps"] == fixed["steps"]
    assert learned_run["command"].replace(" --learn-candidates --candidates-lr 0.01", "") == \
        fixed["command"].replace("runs/G16VV-cpu ", "runs/G16VV-cpu-learned ")
    train_list = np.array(by[("paper-test1", "fixed list", "train")]["candidates"])
    lists = {k: np.array(by[k]["candidates"]) for k in keys}
    for k, cand in lists.items():
        assert cand.shape == (16,) and np.all(np.diff(cand) > 0), k
        assert cand[0] == pytest.approx(0.5) and cand[-1] == pytest.approx(100.0), k
        if k[2] in ("supervised", "photometric", "learned"):
            assert not np.allclose(cand, train_list), k          # the list moved
    # The ring's recomputed list is the closed form at its 0.5 m camera spacing.
    theta = np.linspace(np.arctan(0.5 / 0.5), np.arctan(0.5 / 100.0), 16)
    np.testing.assert_allclose(lists[("ring5-0.5m", "fixed list", "spacing")],
                               0.5 / np.tan(theta), rtol=1e-5)
    assert by[("ring5-0.5m", "fixed list", "train")]["cameras"] == 5
    # Each adapted list is the file the adaptation wrote, and that file is what was evaluated.
    adapted = {(a["rig"], a["loss"]): a for a in doc["adaptation"]}
    assert set(adapted) == {(rig, loss) for rig in ("paper-test2", "paper-test3", "ring5-0.5m")
                            for loss in ("supervised", "photometric")}
    for (rig, loss), a in adapted.items():
        assert not a["reused"] and a["seconds"] > 0 and math.isfinite(a["last_loss"])
        np.testing.assert_allclose(lists[(rig, "fixed list", loss)], a["candidates"], rtol=1e-6)
        assert json.loads(Path(a["list"]).read_text())["candidates"] == a["candidates"]
        assert a["command"].startswith("gijax adapt-candidates --ckpt ")
    assert {r["layout"]: r["mae_vs_spacing_percent"] is None for r in doc["rows"]} == {
        "paper-test1": True, "paper-test2": False, "paper-test3": False, "ring5-0.5m": False}
    assert [c["claim"][:4] for c in doc["claims"]] == ["(L1)", "(L2)", "(L3)", "(L4)"]
    for c in doc["claims"]:
        assert c["status"] in ("PASS", "FAIL")
    for c in doc["claims"][:3]:
        assert set(c["numbers"]) == {"paper-test2", "paper-test3", "ring5-0.5m"}
    assert "smoke scale" in doc["verdict"] and ("? Yes" in doc["verdict"]
                                                or "? No" in doc["verdict"])
    md = learned["out"].with_suffix(".md").read_text()
    for text in (doc["verdict"], "## Claims", "## Adaptation", "## The lists", "## Provenance",
                 "paper's recomputed (spacing)", "adapted, photometric"):
        assert text in md
    prov = doc["provenance"]
    for field in PROVENANCE_FIELDS:
        assert field in prov, field
    assert prov["command"].startswith("python experiments/learned_candidates.py --scale smoke")


@pytest.mark.slow
def test_learned_candidates_data_and_figures(learned):
    doc = learned["docs"]["first"]
    work = Path(doc["provenance"]["work"])
    seeds = {d["role"]: d["seed"] for d in doc["provenance"]["datasets"]}
    assert seeds["ring5-0.5m"] == 105 and seeds["adapt-ring5-0.5m"] == 205
    # Adaptation scenes are never test scenes (nor training ones); the check says so.
    tests = ("paper-test1", "paper-test2", "paper-test3", "ring5-0.5m")
    adapt = [f"adapt-{r}" for r in tests[1:]]
    assert learned_candidates.check_adaptation_separate(work, adapt, tests) == dict.fromkeys(
        adapt, 0)
    with pytest.raises(ValueError, match="adaptation data shares scene seeds"):
        learned_candidates.check_adaptation_separate(work, ["ring5-0.5m"], tests)
    assert (work / "rigs" / "ring5-0.5m.yaml").is_file()
    # Every list, EV and GI on every rig, with its pixel steps.
    lists = {(s["rig"], s["list"]): s for s in doc["lists"]}
    for rig in tests:
        assert {(rig, "EV"), (rig, "GI")} <= set(lists)
    assert len([k for k in lists if k[0] == "ring5-0.5m"]) == 8
    for s in doc["lists"]:
        assert len(s["steps_px"]) == 15 and min(s["steps_px"]) > 0
    # The rig-aware list takes equal mean steps by construction; EV's equal steps in inverse
    # distance move a feature less near the rig than far from it (the parallax angle saturates).
    for rig in tests[1:]:
        assert lists[(rig, "rig-aware GI")]["min_max_ratio"] == pytest.approx(1.0, abs=1e-3)
    ev = lists[("paper-test2", "EV")]
    assert ev["steps_px"][0] < ev["steps_px"][-1]
    for name in ("lists", *tests):
        png = learned["out"].with_name(f"learned_{name}.png")
        img = cv2.imread(str(png))
        assert img is not None and img.shape[0] > 200, png


@pytest.mark.slow
def test_learned_candidates_rerun_reuses_everything(learned):
    first, second = learned["docs"]["first"], learned["docs"]["second"]
    assert all(r["reused"] for r in second["rows"])
    assert all(a["reused"] for a in second["adaptation"])
    assert all(r["reused"] for r in second["training"].values())
    assert [r["mae"] for r in second["rows"]] == [r["mae"] for r in first["rows"]]
    assert [a["candidates"] for a in second["adaptation"]] == \
        [a["candidates"] for a in first["adaptation"]]
    assert learned["seconds"]["second"] < learned["seconds"]["first"]


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
    np.testing.assert_allclose(metrics["mae_per_sample"], paper_mae, rtol=1e-5)
    # gijax's beside them: clamped labels pooled over all estimated pixels.
    assert metrics["mae_gijax"] == pytest.approx(np.abs(errs).mean(), rel=1e-5)
    assert metrics["rmse_gijax"] == pytest.approx(np.sqrt((errs ** 2).mean()), rel=1e-5)
    assert metrics["pixels_gijax"] == est_count > metrics["pixels"]
    assert metrics["coverage"] == pytest.approx(est_count / lab_count)
    assert metrics["samples"] == 2
    np.testing.assert_array_equal(np.isnan(first), ~ests[0])


def test_paired_difference_against_a_closed_case():
    """Scene-by-scene differences: a constant shift has a zero-width CI at the shift; noise
    around zero gives a CI that spans it; scenes without a value drop out in pairs."""
    base = np.linspace(0.05, 0.15, 40)
    p = claims.paired_difference(list(base - 0.01), list(base))
    assert p["mean"] == pytest.approx(-0.01) and p["lower"] == p["scenes"] == 40
    assert p["ci95"] == pytest.approx([-0.01, -0.01])
    rng = np.random.default_rng(0)
    noise = rng.normal(0.0, 0.01, 400)
    q = claims.paired_difference(list(base.repeat(10) + noise), list(base.repeat(10)))
    assert q["ci95"][0] < 0 < q["ci95"][1]
    # The bootstrap CI of a mean: about +-1.96 sd / sqrt(n).
    assert q["ci95"][1] - q["ci95"][0] == pytest.approx(2 * 1.96 * noise.std() / 20, rel=0.15)
    r = claims.paired_difference([0.1, None, 0.3, 0.2], [0.2, 0.1, None, 0.1])
    assert r["scenes"] == 2 and r["mean"] == pytest.approx(0.0) and r["lower"] == 1
    assert claims.paired_difference([0.1], [0.2]) is None
    assert claims.paired_difference([0.1, 0.2], [0.2]) is None
    assert claims.paired_difference(None, [0.2]) is None
    assert "95 % CI -0.0100..-0.0100" in claims.paired_text(p) and "40/40" in claims.paired_text(p)


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


def test_ring_rig_is_a_pentagon_with_half_metre_spacing():
    from gijax.candidates import camera_spacing

    rig = learned_candidates.ring_rig()
    t = np.asarray(rig.translations, np.float64)
    assert rig.num_cameras == 5
    assert float(camera_spacing(rig)) == pytest.approx(0.5, abs=1e-6)
    np.testing.assert_allclose(np.asarray(rig.reference), t.mean(0), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(t - t.mean(0), axis=1), 0.25 / np.sin(np.pi / 5),
                               rtol=1e-6)
    # Its seeds are its own: none is a seed of the other experiments.
    assert not set(learned_candidates.SEEDS.values()) & set(scales.DATA_SEEDS.values())


def _list_rows(**mae):
    """Rows of the learned-candidates table: ``rig__training__list=mae``."""
    rows = []
    for key, v in mae.items():
        layout, training, lst = key.split("__")
        rows.append({"layout": layout.replace("_", "-"), "training": training.replace("_", " "),
                     "list": lst, "mae": v})
    return rows


def test_learned_list_claims_need_every_new_rig():
    rigs = {"paper_test2": 0.050, "paper_test3": 0.060, "ring5-0.5m": 0.040}
    spacing = {f"{r}__fixed_list__spacing": v for r, v in rigs.items()}
    better = {f"{r}__fixed_list__supervised": 0.9 * v for r, v in rigs.items()}
    rows = _list_rows(**spacing, **better)
    c = learned_candidates.claim_beats_paper_list(rows, "supervised")
    assert c["status"] == "PASS" and c["claim"].startswith("(L1)")
    assert c["numbers"]["paper-test3"]["change_percent"] == pytest.approx(-10.0)
    assert learned_candidates.claim_beats_paper_list(rows, "photometric")["status"] == "N/A"
    assert "? Yes**: the supervised-adapted list lowers" in learned_candidates.verdict(
        [c], scales.SCALES["cpu"])
    # Worse on one rig: not a win, whatever the others say.
    rows = _list_rows(**spacing, **{**better, "ring5-0.5m__fixed_list__supervised": 0.041})
    c = learned_candidates.claim_beats_paper_list(rows, "supervised")
    assert c["status"] == "FAIL" and "+2.5 %" in c["detail"]
    assert "? No**" in learned_candidates.verdict([c], scales.SCALES["cpu"])
    # The learned list is compared with the fixed-list model's 'spacing' row.
    learned = {f"{r}__learned_list__learned": 0.5 * v for r, v in rigs.items()}
    c = learned_candidates.claim_beats_paper_list(_list_rows(**spacing, **learned), "learned")
    assert c["status"] == "PASS" and c["numbers"]["paper-test2"]["spacing"] == 0.050
    same = _list_rows(paper_test1__fixed_list__train=0.03, paper_test1__learned_list__learned=0.03)
    assert learned_candidates.claim_learning_costs_nothing(same)["status"] == "PASS"
    same[1]["mae"] = 0.031
    assert learned_candidates.claim_learning_costs_nothing(same)["status"] == "FAIL"
    # With per-scene MAEs the verdict says where the gain stands out from the scene spread:
    # a uniform 10 % gain on two rigs, a gain on average only (half the scenes worse) on one.
    rows = _list_rows(**spacing, **better)
    scenes = np.linspace(0.5, 1.5, 20)
    for r in rows:
        r["mae_per_sample"] = list(r["mae"] * scenes)
        if (r["layout"], r["list"]) == ("ring5-0.5m", "supervised"):
            r["mae_per_sample"] = list(r["mae"] * scenes + 0.02 * (-1) ** np.arange(20))
    c = learned_candidates.claim_beats_paper_list(rows, "supervised")
    assert c["status"] == "PASS"
    assert "lower on 20/20" in c["detail"] and "lower on 10/20" in c["detail"]
    text = learned_candidates.verdict([c], scales.SCALES["cpu"])
    assert "below 0) on `paper-test2`, `paper-test3`; on `ring5-0.5m` it does not." in text


def test_concat_models_cannot_take_four_cameras():
    from gijax.nn.presets import get_preset

    assert "exactly 3 cameras" in new_layout.unsupported(get_preset("E16-cpu"), 4)
    assert new_layout.unsupported(get_preset("E16-cpu"), 3) is None
    assert new_layout.unsupported(get_preset("G16VV-cpu"), 4) is None


def test_method_figure_draws_every_panorama_at_one_size_and_its_own_aspect(monkeypatch):
    """Truth, predictions and errors at one size and the panorama's aspect (a 3-camera rig
    once drew predictions a third of the row wide and the truth stretched across it)."""
    import matplotlib.pyplot as plt

    drawn, close = {}, plt.close
    monkeypatch.setattr(reporting, "save_png",
                        lambda fig, path, dpi: drawn.update(fig=fig, path=path))
    monkeypatch.setattr(plt, "close", lambda fig: None)
    h, w = 16, 64
    dist = np.full((h, w), 4.0)
    dist[:4, :8] = np.inf                                      # unlabelled pixels
    sample = {"pano_distance": dist, "images": np.zeros((3, 32, 32, 3), np.uint8)}
    panels = [("a", np.full((h, w), 0.25)), ("b", np.full((h, w), 0.3))]
    reporting.save_figure(Path("x.png"), sample, panels, "title")
    fig = drawn["fig"]
    fig.canvas.draw()
    maps = [ax for ax in fig.axes if ax.images and ax.images[0].get_array().shape == (h, w)]
    assert len(maps) == 1 + 2 * len(panels)
    sizes = np.array([ax.get_window_extent().size for ax in maps])
    np.testing.assert_allclose(sizes, np.broadcast_to(sizes[0], sizes.shape), rtol=0.02)
    assert sizes[0, 0] / sizes[0, 1] == pytest.approx(w / h, rel=0.03)
    # Error panels share one colour scale with a bar, as the inverse distances do.
    bars = [ax.get_xlabel() for ax in fig.axes if ax.get_xlabel()]
    assert any("|error|" in b for b in bars) and any("inverse distance" in b for b in bars)
    close(fig)                               # plt.close itself is patched away above


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


def test_network_adaptation_commands_parse_and_claims_compare_scene_by_scene(tmp_path):
    """The recorded ``gijax adapt`` command is one gijax's own parser accepts with the weights
    the script passes; the claims pair scenes and say whether the mean fell."""
    import shlex

    from experiments import network_adaptation as na
    from gijax.cli import build_parser

    cfg = na.SCALES["cpu"]
    for name, (_, weights) in na.VARIANTS.items():
        weights = {**weights, "teacher": weights["teacher"] if weights["teacher"] is not None
                   else cfg["teacher"]}
        argv = na.adapt_argv("G16VV-cpu-zncc", tmp_path / "frames", tmp_path / "out", cfg,
                             weights, tmp_path / "test")
        args = build_parser().parse_args(shlex.split(na.gijax_command(argv))[1:])
        assert (args.ckpt, args.steps, args.lr, args.batch) == ("G16VV-cpu-zncc", cfg["steps"],
                                                                cfg["lr"], cfg["batch"])
        assert (args.photometric, args.smoothness, args.teacher, args.occlusion) == (
            weights["photometric"], weights["smoothness"], weights["teacher"],
            weights["occlusion"])
    rows = {"before": {"mae": 0.05, "mae_per_sample": [0.04, 0.06, None]},
            na.TEACHER: {"mae": 0.03, "mae_per_sample": [0.03, 0.03, 0.02]},
            "photometric": {"mae": 0.045, "mae_per_sample": [0.035, 0.055, 0.01]},
            "occlusion": {"mae": 0.046, "mae_per_sample": [0.03, 0.06, 0.02]},
            "teacher": {"mae": 0.04, "mae_per_sample": [0.03, 0.05, 0.01]}}
    out = {t: (p, h) for t, p, h in na.comparisons(rows)}
    p, holds = out["photometric vs before"]
    assert holds and p["scenes"] == 2 and p["lower"] == 2 and abs(p["mean"] + 0.005) < 1e-12
    p, holds = out["occlusion vs photometric"]
    assert not holds and p["scenes"] == 3 and p["lower"] == 1 and abs(p["mean"] - 0.01 / 3) < 1e-12
    p, holds = out[f"teacher vs {na.TEACHER}"]
    assert not holds and p["scenes"] == 3 and abs(p["mean"] - 0.01 / 3) < 1e-12


def test_example_rig_commands_parse_and_compare_scene_by_scene():
    """The example-rig experiment's recorded commands are ones gijax's own parser accepts with
    the recipe's values (the fine-tuning reads images at the rendered scale); its comparisons
    pair the scenes of two methods' ``gijax eval --json`` and say whether the mean is lower."""
    import shlex

    from experiments import example_rig as ex
    from gijax.cli import build_parser

    cfg = ex.SCALES["cpu"]
    parse = build_parser().parse_args
    args = parse(shlex.split(ex.gijax_command(ex.train_argv(cfg)))[1:])
    assert (args.preset, args.init_from, args.steps, args.batch, args.lr) == (
        ex.MODEL, ex.MODEL, cfg["steps"], cfg["batch"], cfg["lr"])
    assert args.override == [("image_scale", cfg["image_scale"])]
    args = parse(shlex.split(ex.gijax_command(ex.render_argv(cfg, "test")))[1:])
    assert (args.samples, args.seed, args.scale) == (cfg["test"], ex.SEEDS["test"],
                                                    cfg["image_scale"])
    assert len(set(ex.SEEDS.values())) == 3            # held-out scenes share no seed
    for method in ("after", ex.BASELINE):
        args = parse(shlex.split(ex.gijax_command(ex.eval_argv(method, "runs/x", "e.json")))[1:])
        assert args.method == ("rtss" if method == ex.BASELINE else "learned")
        args = parse(shlex.split(ex.gijax_command(ex.predict_argv(method, "runs/x", "p")))[1:])
        assert len(args.images) == len(ex.CAMERAS)

    def row(maes):
        return {"mae": float(np.mean(maes)), "per_scene": [{"mae": m} for m in maes]}

    rows = {"before": row([0.20, 0.30, 0.25]), "after": row([0.04, 0.06, 0.02]),
            ex.BASELINE: row([0.05, 0.05, 0.05])}
    out = {t: (p, h) for t, p, h in ex.comparisons(rows)}
    p, holds = out[f"after vs {ex.BASELINE}"]
    assert holds and p["scenes"] == 3 and p["lower"] == 2 and abs(p["mean"] + 0.01) < 1e-12
    p, holds = out[f"before vs {ex.BASELINE}"]
    assert not holds and p["lower"] == 0


def test_demo_seeds_command_parses_and_rows_pick_the_best_list_and_count_wins():
    """The fixed-seed demo experiment records a ``gijax demo`` command gijax's parser accepts
    with its seed, scene count and model; per rig it takes the learned list with the lowest
    mean MAE and counts the scenes it wins against the baseline (a hand-made demo table)."""
    import shlex

    from experiments import demo_seeds as ds
    from gijax.cli import build_parser

    args = build_parser().parse_args(
        shlex.split(ds.gijax_command(ds.demo_argv(4, 3, "G16VV-cpu-zncc", Path("o/seed-4"))))[1:])
    assert (args.seed, args.scenes, args.model, args.baseline, args.out) == (
        4, 3, "G16VV-cpu-zncc", ds.BASELINE, "o/seed-4")
    assert len(set(ds.SCALES["cpu"]["seeds"])) == 5

    def method(maes):
        return {"mae": float(np.mean(maes)), "mae_per_scene": maes}

    doc = {"table": {
        "paper-train": {"M training": method([0.03, 0.05, 0.04]),
                        "M spacing": method([0.02, 0.06, 0.01]),
                        ds.BASELINE: method([0.025, 0.02, 0.02])},
        "paper-test3": {"M training": method([0.09, 0.08, 0.07]),
                        "M spacing": method([0.10, 0.10, 0.10]),
                        ds.BASELINE: method([0.08, 0.09, 0.095])}}}
    rows = {r["rig"]: r for r in ds.seed_rows(7, doc)}
    train, test3 = rows["paper-train"], rows["paper-test3"]
    assert train["method"] == "M spacing" and train["scenes_won"] == 2 and train["ahead"] is False
    assert test3["method"] == "M training" and test3["scenes_won"] == 2 and test3["ahead"] is True
    assert train["seed"] == 7 and train["scenes"] == 3
    assert abs(test3["baseline_mae"] - np.mean([0.08, 0.09, 0.095])) < 1e-12


def test_weight_average_refuses_to_replace_the_bundle_it_compares_and_names_a_missing_pack(
        tmp_path, capsys):
    """The averaging script checks its arguments before any work: publishing over the bundle
    it is compared with is refused in one line; a revision without the pack is named."""
    from experiments import weight_average as wa

    bundle = tmp_path / "bundle"
    with pytest.raises(SystemExit) as exc:
        wa.main(["--scale", "cpu", "--work", str(tmp_path), "--previous", str(bundle),
                 "--publish", str(bundle), "--results", "none"])
    assert exc.value.code == 2
    assert "would replace the --previous bundle" in capsys.readouterr().err
    assert not (tmp_path / "data").exists()
    with pytest.raises(ValueError, match=r"^revision 0{40}: no experiments/packs/x/pack.json"):
        wa.extract_pack("0" * 40, "experiments/packs/x", tmp_path / "pack")


def test_resolution_floor_oracles_against_hand_built_labels(tmp_path):
    """The oracles of experiments/resolution_floor.py on labels whose answers are known: a map
    constant on each 2 x 2 cell is reproduced exactly by the repeated cell means, a map at the
    candidates by the nearest candidate, and a map with a step inside a cell is not."""
    from experiments import resolution_floor as RF

    cand = np.array([0.5, 1.0, 2.0, 4.0, 100.0])
    rng = np.random.default_rng(3)
    cells = 1.0 / rng.choice(cand, size=(4, 8))
    blocky = np.repeat(np.repeat(cells, 2, axis=0), 2, axis=1)          # (8, 16)
    usable = np.ones_like(blocky, bool)
    maps = RF.oracle_maps(blocky, usable, 2, cand)
    np.testing.assert_allclose(maps["cell mean, repeated"], blocky, rtol=1e-12)
    np.testing.assert_allclose(maps["nearest candidate"], blocky, rtol=1e-12)
    # A step from 1/1 m to 1/2 m between the two columns of every cell: the cell mean is the
    # average 0.75, 0.25 1/m from either side, wherever the map is repeated.
    step = np.tile(np.array([1.0, 0.5]), (8, 8))
    maps = RF.oracle_maps(step, usable, 2, cand)
    np.testing.assert_allclose(np.abs(maps["cell mean, repeated"] - step), 0.25, rtol=1e-12)
    # Unusable pixels do not enter a cell's mean.
    holes = usable.copy()
    holes[:, 1::2] = False
    np.testing.assert_allclose(RF.oracle_maps(step, holes, 2, cand)["cell mean, repeated"], 1.0)
    with pytest.raises(ValueError, match="whole number of 2 x 2 cells"):
        RF.oracle_maps(step[:7], usable[:7], 2, cand)
    with pytest.raises(SystemExit) as exc:
        RF.main(["--help"])
    assert exc.value.code == 0
