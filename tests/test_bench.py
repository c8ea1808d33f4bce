"""The benchmark toolkit: timing statistics (synthetic clocks and sleeps), alternation order,
ratios and increments, memory accounting, cost analysis, writers, and the ``gijax bench``
command wired end to end on one small case."""

from __future__ import annotations

import json
import time

import jax.numpy as jnp
import numpy as np
import pytest

from gijax.bench import cost, memory, report, timing
from gijax.bench.rigs import polygon_positions


class FakeClock:
    """A clock that only moves when a fake workload says how long it took."""

    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now

    def work(self, seconds):
        def fn():
            self.now += seconds
            return None
        return fn


def test_time_call_statistics_on_a_synthetic_clock():
    clock = FakeClock()
    durations = iter([7.0, 9.0,  # warm-up calls: never timed
                      0.05, 0.01, 0.04, 0.02, 0.03])

    def fn():
        clock.now += next(durations)

    stats, times = timing.time_call(fn, warmup=2, reps=5, timer=clock)
    assert times == pytest.approx([0.05, 0.01, 0.04, 0.02, 0.03])
    # Linear-interpolation quartiles of 0.01..0.05: 0.02, 0.03, 0.04.
    assert stats.median == pytest.approx(0.03)
    assert stats.q1 == pytest.approx(0.02) and stats.q3 == pytest.approx(0.04)
    assert stats.iqr == pytest.approx(0.02)
    assert (stats.min, stats.max) == pytest.approx((0.01, 0.05))
    assert stats.mean == pytest.approx(0.03)
    ms = stats.as_dict("x_", factor=1e3)
    assert ms["x_median"] == pytest.approx(30.0) and ms["x_iqr"] == pytest.approx(20.0)
    assert ms["x_n"] == 5


def test_time_call_real_sleep_lower_bound():
    # Sleeping guarantees at least the requested time; only that bound is asserted.
    stats, times = timing.time_call(lambda: time.sleep(0.004), warmup=0, reps=3)
    assert len(times) == 3 and stats.min >= 0.004
    assert stats.q1 <= stats.median <= stats.q3 <= stats.max


def test_time_call_blocks_on_results():
    waited = []

    class Pending:
        def block_until_ready(self):
            waited.append(1)
            return self

    timing.time_call(lambda: {"a": Pending(), "b": [Pending(), 3]}, warmup=1, reps=2)
    assert len(waited) == 6  # 3 calls x 2 pending leaves


def test_time_alternating_rotates_and_pairs():
    clock = FakeClock()
    order = []
    cost_of = {"a": 0.2, "b": 0.1, "c": 0.4}

    def make(name):
        def fn():
            order.append(name)
            clock.now += cost_of[name]
        return fn

    times = timing.time_alternating({k: make(k) for k in "abc"}, warmup=1, reps=3, timer=clock)
    assert order == list("abc") + list("abc") + list("bca") + list("cab")
    assert times["a"] == pytest.approx([0.2] * 3) and times["c"] == pytest.approx([0.4] * 3)
    r = timing.paired_ratio(times["c"], times["b"])
    assert r.median == pytest.approx(4.0) and r.iqr == pytest.approx(0.0)


def test_paired_ratio_and_increment():
    r = timing.paired_ratio([2.0, 4.0, 9.0], [1.0, 2.0, 3.0])
    assert r.median == pytest.approx(2.0) and r.max == pytest.approx(3.0)
    inc = timing.linear_increment([5, 3, 4], [10 + 6 * 5, 10 + 6 * 3, 10 + 6 * 4])
    assert inc["slope"] == pytest.approx(6.0) and inc["intercept"] == pytest.approx(10.0)
    assert inc["steps"] == pytest.approx([6.0, 6.0]) and inc["counts"] == [3, 4, 5]
    inc = timing.linear_increment([8, 16, 32], [1.0, 2.0, 6.0])
    assert inc["steps"] == pytest.approx([1 / 8, 4 / 16])


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="at least one"):
        timing.timing_stats([])
    with pytest.raises(ValueError, match="finite"):
        timing.timing_stats([1.0, float("nan")])
    with pytest.raises(ValueError, match="reps"):
        timing.time_call(lambda: None, reps=0)
    with pytest.raises(ValueError, match="equal length"):
        timing.paired_ratio([1.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="distinct"):
        timing.linear_increment([3, 3], [1.0, 2.0])


def test_matmul_cost_analysis_and_memory_analysis():
    m, k, n = 24, 7, 5
    a, b = jnp.ones((m, k)), jnp.ones((k, n))
    compiled = cost.compile_fn(lambda x, y: x @ y, a, b)
    c = cost.cost_of(compiled)
    assert c["flops"] == 2 * m * n * k
    mem = memory.compiled_memory(compiled)
    assert mem["argument_bytes"] == 4 * (m * k + k * n)
    assert mem["output_bytes"] == 4 * m * n
    assert mem["peak_bytes"] >= mem["argument_bytes"] + mem["output_bytes"] - mem["alias_bytes"]


def test_efficiency_arithmetic():
    e = cost.efficiency({"flops": 4e9, "bytes_accessed": 1e9}, 0.5,
                        {"flops_per_s": 16e9, "bytes_per_s": 4e9})
    assert e["gflops_per_s"] == pytest.approx(8.0) and e["gbytes_per_s"] == pytest.approx(2.0)
    assert e["frac_peak_flops"] == pytest.approx(0.5) and e["frac_bandwidth"] == pytest.approx(0.5)
    assert e["roofline_s"] == pytest.approx(0.25) and e["frac_roofline"] == pytest.approx(0.5)
    assert e["flops_per_byte"] == pytest.approx(4.0)


def test_peak_rss_sees_an_allocation():
    with memory.PeakRSS() as peak:
        block = np.ones(64 * 2**20 // 8)  # 64 MiB, every page written
        time.sleep(0.01)
    del block
    assert peak.growth_bytes >= 48 * 2**20
    assert memory.device_memory() == {} or "bytes_in_use" in memory.device_memory()


def test_json_and_markdown_writers(tmp_path):
    path = report.write_json(tmp_path / "sub" / "r.json",
                             {"a": np.float32(1.5), "b": np.arange(3), "c": float("nan"),
                              "d": (np.int64(2), None)})
    assert json.loads(path.read_text()) == {"a": 1.5, "b": [0, 1, 2], "c": None, "d": [2, None]}
    assert [p.name for p in path.parent.iterdir()] == ["r.json"]  # no temp file left
    rows = [{"name": "x|y", "ms": 1.234, "n": 3}, {"name": "z", "ms": None, "n": 10}]
    cols = [("name", "name"), ("time ms", "ms", ".1f"), ("n", "n"),
            ("pct", "ms", lambda v: f"{100 * v:.0f}%")]
    assert report.markdown_table(rows, cols) == (
        "| name | time ms | n | pct |\n"
        "| --- | ---: | ---: | ---: |\n"
        "| x\\|y | 1.2 | 3 | 123% |\n"
        "| z |  | 10 |  |")
    text = report.text_table(rows, cols).splitlines()
    assert text[0].split() == ["name", "time", "ms", "n", "pct"] and len(text) == 4
    assert report.markdown_grid(["a", "b"], [["1", "x|y"]], numeric=[True, False]) == (
        "| a | b |\n| ---: | --- |\n| 1 | x\\|y |")
    with pytest.raises(ValueError, match="one alignment per column"):
        report.markdown_grid(["a", "b"], [], numeric=[True])


def test_git_revision_ignores_the_named_paths(tmp_path):
    import subprocess

    from gijax.bench.machine import git_revision

    def git(*args):
        subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args],
                       cwd=tmp_path, check=True, capture_output=True)

    git("init", "-q")
    (tmp_path / "results").mkdir()
    (tmp_path / "code.py").write_text("a = 1\n")
    (tmp_path / "results" / "table.md").write_text("old\n")
    git("add", ".")
    git("commit", "-q", "-m", "start")
    head = git_revision(tmp_path)
    assert len(head["commit"]) == 40 and head["dirty"] is False
    (tmp_path / "results" / "table.md").write_text("new\n")
    assert git_revision(tmp_path)["dirty"] is True
    assert git_revision(tmp_path, ignore=["results"])["dirty"] is False
    (tmp_path / "code.py").write_text("a = 2\n")
    assert git_revision(tmp_path, ignore=["results"]) == {"commit": head["commit"], "dirty": True}
    assert git_revision(tmp_path.parent / "no-such-folder") == {"commit": None, "dirty": None}


def test_polygon_rig_positions():
    for n in (3, 4, 5):
        p = polygon_positions(n, 1.0)
        edges = np.linalg.norm(p - np.roll(p, 1, axis=0), axis=1)
        assert edges == pytest.approx(np.ones(n))
        assert p.mean(0) == pytest.approx(np.zeros(3), abs=1e-12)
    with pytest.raises(ValueError, match="camera count"):
        polygon_positions(1)


def test_select_device():
    from gijax.bench.suite import select_device

    assert select_device("cpu").platform == "cpu"
    with pytest.raises(ValueError, match="cpu' or 'gpu"):
        select_device("tpu")
    try:
        dev = select_device("gpu")
    except ValueError as exc:
        assert "no GPU" in str(exc)
    else:
        assert dev.platform == "gpu"


def test_scaling_figure_writes_png(tmp_path):
    from gijax.bench.plots import scaling_figure

    def row(c, d, ms):
        return {"preset": "P", "cameras": c, "candidates": d, "ms_median": ms, "ms_q1": ms - 1,
                "ms_q3": ms + 1, "xla_peak_mib": 10.0 * c + d}

    rows = [row(3, 16, 10), row(4, 16, 12), row(5, 16, 14), row(3, 8, 6), row(3, 32, 19)]
    rtss = {"rows": [row(3, 32, 50), row(4, 32, 70)]}
    out = scaling_figure({"rows": rows}, tmp_path / "s.png", rtss=rtss)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_gijax_bench_command_writes_json_and_markdown(tmp_path, capsys):
    from gijax.cli import main

    out = tmp_path / "bench"
    rc = main(["bench", "--suite", "quick", "--cases", "candidates", "--reps", "2",
               "--warmup", "0", "--out", str(out), "--quiet"])
    assert rc == 0
    result = json.loads((out / "bench.json").read_text())
    assert list(result["cases"]) == ["candidates"]
    row = result["cases"]["candidates"]["rows"][0]
    assert (row["rig"], row["cameras"], row["n"]) == ("paper-test2", 3, 16)
    assert row["solve_ms_median"] > 0 and row["grad_ms_median"] > 0
    cal = result["calibration"]
    assert cal["matmul"]["xla_flops"] == 2 * cal["matmul"]["n"] ** 3
    assert cal["limits"]["flops_per_s"] > 0 and cal["limits"]["bytes_per_s"] > 0
    assert result["machine"]["backend"] == "cpu" and "jax" in result["machine"]["versions"]
    md = (out / "bench.md").read_text()
    assert "## Rig-aware GI candidates" in md and "| paper-test2 | 3 | 16 |" in md
    assert "## Calibration" in md and "git revision" in md
    assert "quick suite" in capsys.readouterr().out
    with pytest.raises(SystemExit):  # argparse rejects an unknown case name
        main(["bench", "--cases", "nope"])


def test_isolated_case_configs_and_table():
    """The isolated case: '-plain' swaps in plain features and nothing else; its table shows
    whole / sum and the peaks next to the PyTorch reference; it never runs unless named."""
    import dataclasses

    from gijax.bench.isolated import PYTORCH_REFERENCE, bench_config
    from gijax.bench.suite import DEFAULT_CASES, SUITES, case_tables
    from gijax.nn.presets import get_preset

    plain = bench_config("G16VV-cpu-plain")
    base = get_preset("G16VV-cpu")
    assert base.features != "plain" and plain.features == "plain"
    assert dataclasses.replace(plain, name=base.name, features=base.features) == base
    assert bench_config("G16V-released") == get_preset("G16V-released")
    assert "isolated" not in DEFAULT_CASES
    assert set(PYTORCH_REFERENCE) <= set(SUITES["full"].isolated_presets)
    row = {"preset": "G16VV-plain", "features_s": 0.7, "sweep_s": 0.1, "cost_volume_s": 0.1,
           "unet_s": 2.5, "regress_s": 0.02, "sum_s": 3.42, "whole_s": 3.4,
           "whole_over_sum": 3.4 / 3.42, "peak_gb": 1.31, "pytorch_s": 5.1,
           "pytorch_peak_gb": 1.46, "onnx_mb": 204.0, "ort_default_s": 3.9,
           "ort_default_peak_gb": 2.9, "ort_low_s": 4.4, "ort_low_peak_gb": 0.98}
    tables = case_tables({"calibration": {"rows": []}, "cases": {"isolated": {"rows": [row]}}})
    title, rows, cols = tables[-1]
    assert "fresh processes" in title
    text = report.markdown_table(rows, cols)
    assert "whole / sum" in text and "| G16VV-plain |" in text
    assert "| 0.99 |" in text and "| 1.31 |" in text and "| 0.98 |" in text


def test_torch_peer_rows_pool_the_steps_and_pair_the_rounds():
    """A row pools every step of every round (min / median / max), takes each framework's
    worst peak and the median of the per-round ratios of medians."""
    from gijax.bench.torch_peer import peer_row

    def child(steps, peak, **extra):
        return {"step_s": steps, "s_median": float(np.median(steps)), "peak_gb": peak,
                "build_s": 1.0, "version": "v", "cpus": 2, **extra}

    runs = {"gijax": [child([1.0, 2.0, 3.0], 0.5), child([2.0, 4.0], 0.7)],
            "pytorch": [child([1.0, 1.0, 1.0], 0.9, threads=2, imported_jax=False),
                        child([2.0, 2.0], 0.8, threads=2, imported_jax=False)]}
    row = peer_row("G16VV-cpu", "train", 8, runs)
    assert (row["gijax_s_min"], row["gijax_s_median"], row["gijax_s_max"]) == (1.0, 2.0, 4.0)
    assert row["pytorch_s_median"] == 1.0 and row["pytorch_samples_per_s"] == 8.0
    # Round medians 2 / 1 and 3 / 2.
    assert row["ratio_per_round"] == [2.0, 1.5] and row["gijax_over_pytorch"] == 1.75
    assert row["gijax_peak_gb"] == 0.7 and row["pytorch_peak_gb"] == 0.9
    assert row["pytorch_imported_jax"] is False and row["rounds"] == 2


def test_torch_peer_checks_presets_and_skips_without_torch(tmp_path):
    """Presets the twin cannot build fail before anything runs, naming the choice; without
    torch the case is one line and no rows; it runs only when named."""
    from gijax.bench.suite import DEFAULT_CASES, case_tables
    from gijax.bench.torch_peer import check_presets, measure_peers

    assert "torch-peer" not in DEFAULT_CASES
    with pytest.raises(ValueError, match="refine=True"):
        check_presets(["G16VV-cpu-refine"])
    with pytest.raises(ValueError, match="unknown model preset 'nope'"):
        check_presets(["G16VV-cpu", "nope"])
    lines = []
    missing = str(tmp_path / "no-python")
    got = measure_peers(["G16VV-cpu"], torch_python=missing, log=lines.append)
    assert got["rows"] == [] and "torch is not installed for " + missing in got["skipped"]
    assert len(lines) == 1 and lines[0].startswith("torch-peer: skipped: ")
    tables = case_tables({"calibration": {"rows": []}, "cases": {"torch-peer": got}})
    title, rows, cols = tables[-1]
    assert "skipped, torch is not installed" in title and cols == []


def test_gijax_bench_torch_peer_options(tmp_path, capsys):
    """The case's options reach its settings; a preset the twin cannot build is one error
    before the calibration; without torch the run still writes its report."""
    from gijax.cli import main

    assert main(["bench", "--cases", "torch-peer", "--torch-presets", "G16VV-cpu-refine",
                 "--out", str(tmp_path / "bad")]) == 1
    assert "refine=True" in capsys.readouterr().err and not (tmp_path / "bad").exists()
    out = tmp_path / "peer"
    assert main(["bench", "--cases", "torch-peer", "--torch-presets", "G16VV-cpu",
                 "--torch-batches", "2", "--torch-modes", "infer", "--torch-rounds", "1",
                 "--torch-python", str(tmp_path / "no-python"), "--reps", "1",
                 "--warmup", "0", "--out", str(out), "--quiet"]) == 0
    result = json.loads((out / "bench.json").read_text())
    s = result["settings"]
    assert (s["torch_presets"], s["torch_batches"], s["torch_modes"], s["torch_rounds"]) == (
        ["G16VV-cpu"], [2], ["infer"], 1)
    assert "torch is not installed" in result["cases"]["torch-peer"]["skipped"]
    assert "skipped, torch is not installed" in (out / "bench.md").read_text()


def test_torch_peer_table_shows_both_frameworks():
    from gijax.bench.suite import case_tables

    row = {"preset": "G16VV-cpu", "mode": "train", "batch": 8, "gijax_s_min": 1.1,
           "gijax_s_median": 1.234, "gijax_s_max": 1.5, "pytorch_s_min": 0.6,
           "pytorch_s_median": 0.72, "pytorch_s_max": 0.9, "gijax_samples_per_s": 6.48,
           "pytorch_samples_per_s": 11.1, "gijax_over_pytorch": 1.714, "gijax_peak_gb": 1.26,
           "pytorch_peak_gb": 0.95, "spherical": "torchvision.ops.deform_conv2d"}
    title, rows, cols = case_tables({"calibration": {"rows": []},
                                     "cases": {"torch-peer": {"rows": [row]}}})[-1]
    text = report.markdown_table(rows, cols)
    assert "PyTorch twin" in title
    assert "| G16VV-cpu | train | 8 | 1.100 | 1.234 | 1.500 | 0.600 | 0.720 | 0.900 |" in text
    assert "| 1.71 |" in text and "| 1.26 | 0.95 | torchvision.ops.deform_conv2d |" in text


def test_precision_case_ratios_table_and_options():
    """The precision case: speed-up and peak ratios against the same preset's fp32 row (hand
    arithmetic), its table, its suite defaults and options; it runs only when named."""
    import argparse

    from gijax.bench.isolated import versus_fp32
    from gijax.bench.suite import DEFAULT_CASES, SUITES, add_arguments, case_tables

    rows = versus_fp32([
        {"preset": "P", "precision": "fp32", "ort_s": 0.6, "peak_gb": 0.20, "onnx_mb": 7.7},
        {"preset": "P", "precision": "int8", "ort_s": 0.4, "peak_gb": 0.25, "onnx_mb": 2.1},
        {"preset": "Q", "precision": "fp16", "ort_s": 1.0, "peak_gb": 0.5, "onnx_mb": 4.0}])
    assert rows[0]["speedup_vs_fp32"] == 1.0 and rows[0]["peak_vs_fp32"] == 1.0
    assert rows[1]["speedup_vs_fp32"] == pytest.approx(1.5)
    assert rows[1]["peak_vs_fp32"] == pytest.approx(1.25)
    assert rows[2]["speedup_vs_fp32"] is None  # no fp32 row of Q
    title, got, cols = case_tables({"calibration": {"rows": []}, "cases": {
        "precision": {"rows": rows, "calibration_scenes": 2}}})[-1]
    text = report.markdown_table(got, cols)
    assert "2 rendered scene(s)" in title and "| P | int8 | 2.1 | 0.400 | 1.50 | 0.25 | 1.25 |" \
        in text
    assert "precision" not in DEFAULT_CASES
    assert SUITES["quick"].precision_presets == ("G16VV-cpu",)
    assert SUITES["full"].precision_presets == ("G16VV-cpu", "G16VV")
    p = argparse.ArgumentParser()
    add_arguments(p)
    a = p.parse_args(["--cases", "precision", "--precision-presets", "G16VV-cpu", "G16VV",
                      "--precision-calibration", "1"])
    assert a.precision_presets == ["G16VV-cpu", "G16VV"] and a.precision_calibration == 1


def test_stage_backward_is_the_gradient_of_the_weights_and_floating_inputs():
    import jax.numpy as jnp

    from gijax.bench.cases.programs import with_backward

    def stage(state, x, seen):           # a floating output and a boolean one, as the sweep
        return state["w"] * x ** 2, seen & (x > 0)

    state, x, seen = {"w": jnp.float32(3.0)}, jnp.asarray([1.0, -2.0, 0.5]), jnp.ones(3, bool)
    total, grads = with_backward(stage, True)(state, x, seen)
    # sum(w x^2) = 15.75; d/dw = sum(x^2); d/dx = 2 w x; the boolean input gets none.
    np.testing.assert_allclose(float(total), 15.75)
    assert len(grads) == 2
    np.testing.assert_allclose(float(grads[0]["w"]), 5.25)
    np.testing.assert_allclose(np.asarray(grads[1]), [6.0, -12.0, 3.0])
    _, (only,) = with_backward(stage, False)(state, x, seen)
    np.testing.assert_allclose(float(only["w"]), 5.25)


def test_train_stages_table_and_options(tmp_path, capsys):
    from gijax.bench.suite import case_tables
    from gijax.cli import main

    rows = [{"preset": "G16VV-cpu", "batch": 8, "stage": "U-Net", "direction": d,
             "ms_median": ms, "ms_iqr": 1.0, "ms_min": ms - 1, "gflop": 2.8,
             "gflops_per_s": 2.8 / ms * 1e3} for d, ms in (("forward", 20.0),
                                                           ("forward + backward", 80.0))]
    rows[1].update(backward_ms=60.0, share=0.31)
    title, got, cols = case_tables({"calibration": {"rows": []},
                                    "cases": {"train-stages": {"rows": rows}}})[-1]
    text = report.markdown_table(got, cols)
    assert title.startswith("Training step by stage (batch 8, training mode")
    assert "| G16VV-cpu | U-Net | forward + backward | 80.0 | 1.0 | 79.0 | 60.0 | 31.0% | 2.8 | 35.0 |" in text
    # A preset or batch the cases cannot use is one error before the calibration.
    assert main(["bench", "--cases", "train-stages", "--train-presets", "G16VV-nope",
                 "--out", str(tmp_path / "bad")]) == 1
    assert "G16VV-nope" in capsys.readouterr().err and not (tmp_path / "bad").exists()
    assert main(["bench", "--cases", "train", "--train-batch", "0",
                 "--out", str(tmp_path / "bad")]) == 1
    assert "--train-batch must be at least 1; found 0" in capsys.readouterr().err
