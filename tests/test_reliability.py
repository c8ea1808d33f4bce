"""Faults and bad input: one writer per folder, complete datasets, read-only evaluation, quiet
fallback from damaged checkpoints, clear errors for wrong output paths and damaged PNGs, and
one convention for invalid pixels in every prediction file."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from gijax.cli import main
from gijax.data import pngio
from gijax.data.check import check_dataset
from gijax.data.reader import DatasetReader
from gijax.data.writer import DatasetWriter, write_dataset
from gijax.io.lock import LOCK_FILE, FolderLock, FolderLockedError
from gijax.io.rigfile import save_rig
from test_data_format import PANO, synthetic_sample, tiny_rig
from test_train_faults import CACHE, child_env, run_child, script  # noqa: F401 - fixture

G8 = [0.5, 0.60103325, 0.73863074, 0.94007016, 1.26849604, 1.91086214, 3.77357055, 100.0]


@pytest.fixture(scope="module")
def rig():
    return tiny_rig()


@pytest.fixture(scope="module")
def dataset(rig, tmp_path_factory):
    root = tmp_path_factory.mktemp("rel") / "data"
    write_dataset(root, lambda i: synthetic_sample(rig, i), rig, PANO, num_samples=4)
    return root


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _snapshot(root: Path) -> dict:
    """Every path under ``root`` with its size and modification time."""
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(root.rglob("*"))}


def _hold_lock(folder: Path, lock_file: Path | None = None) -> subprocess.Popen:
    """A separate process that holds ``folder``'s lock until it is killed."""
    code = ("import sys, time; from gijax.io.lock import FolderLock; "
            f"lock = FolderLock({str(folder)!r}, lock_file={None if lock_file is None else str(lock_file)!r})"
            ".acquire(); print('locked', flush=True); time.sleep(600)")
    proc = subprocess.Popen([sys.executable, "-c", code], env=child_env(CACHE),
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def _kill(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGKILL)
    proc.wait()


# ------------------------------------------------------------------ 1: concurrent writers

SLOW_RENDER = r'''
import os, sys, time
import gijax.render
real, go, calls = gijax.render.render_sample, sys.argv[1], []
def held(*a, **k):
    # After its first sample, this writer waits for the test's go-ahead, so that it is still
    # writing (and holding the folder) while the second writer starts.
    calls.append(1)
    deadline = time.time() + 120
    while len(calls) > 1 and not os.path.exists(go) and time.time() < deadline:
        time.sleep(0.02)
    return real(*a, **k)
gijax.render.render_sample = held
from gijax.cli import main
sys.exit(main(sys.argv[2:]))
'''


def test_second_render_into_a_folder_fails_naming_the_first(tmp_path):
    rig_file = tmp_path / "tiny.yaml"
    save_rig(tiny_rig(), rig_file)
    out = tmp_path / "D"
    args = ["render", "--rig", str(rig_file), "--out", str(out), "--seed", "1", "--pano", "32x8"]
    go = tmp_path / "go"
    first = subprocess.Popen([sys.executable, "-c", SLOW_RENDER, str(go), *args, "--samples", "12"],
                             env=child_env(CACHE, optimised=True), stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    csv = out / "traj_0000" / "files.csv"
    deadline = time.time() + 120
    while time.time() < deadline and first.poll() is None:
        if csv.exists() and len(csv.read_text().splitlines()) >= 2:   # a sample is committed
            break
        time.sleep(0.05)
    assert first.poll() is None, first.communicate()
    second = subprocess.run([sys.executable, "-m", "gijax", *args, "--samples", "11"],
                            env=child_env(CACHE, optimised=True), capture_output=True, text=True,
                            timeout=120)
    assert first.poll() is None, "the first writer finished before the second one tried"
    go.touch()
    out1, err1 = first.communicate(timeout=120)
    assert first.returncode == 0, err1[-2000:]
    assert second.returncode == 1
    lines = [ln for ln in second.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and f"PID {first.pid}" in lines[0] and "being written" in lines[0], \
        second.stderr
    # Every sample of the first writer is listed, nothing else is there, the lock is gone.
    assert "12 samples" in out1
    rows = csv.read_text().splitlines()[1:]
    assert [r.split(",")[0] for r in rows] == [str(i) for i in range(12)]
    assert len(list((out / "traj_0000" / "cam0" / "rgb").glob("*.png"))) == 12
    result = check_dataset(out)
    assert result.ok and result.samples == 12 and result.requested == 12 and not result.notes
    assert not (out / LOCK_FILE).exists()


def test_a_lock_file_planted_as_a_link_is_refused_and_its_target_untouched(tmp_path, rig,
                                                                            capsys):
    """``ln -s ../victim.txt DS/.gijax.lock`` before a writer takes DS: the lock never opens
    through the link (the victim keeps its bytes), and ``gijax render`` says so in one line
    before it renders anything."""
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    folder = tmp_path / "DS"
    folder.mkdir()
    (folder / LOCK_FILE).symlink_to("../victim.txt")
    with pytest.raises(ValueError, match=r"lock file .*\.gijax\.lock is a symbolic link"):
        DatasetWriter(folder, rig, PANO)
    rig_file = tmp_path / "tiny.yaml"
    save_rig(tiny_rig(), rig_file)
    code = main(["render", "--rig", str(rig_file), "--out", str(folder), "--seed", "1",
                 "--pano", "32x8", "--samples", "1"])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert code != 0 and len(err) == 1 and "is a symbolic link" in err[0], err
    assert victim.read_text() == "precious" and (folder / LOCK_FILE).is_symlink()
    assert not (folder / "manifest.json").exists()


def test_stale_lock_of_a_killed_process_is_taken_over(tmp_path, rig):
    folder = tmp_path / "data"
    folder.mkdir()
    holder = _hold_lock(folder)
    try:
        with pytest.raises(FolderLockedError, match=f"PID {holder.pid}") as err:
            DatasetWriter(folder, rig, PANO)
        assert err.value.holder["pid"] == holder.pid
        assert not (folder / "manifest.json").exists()          # nothing written
    finally:
        _kill(holder)
    assert (folder / LOCK_FILE).exists()                        # left behind by the kill
    lock = FolderLock(folder, "dataset").acquire()
    assert lock.previous["pid"] == holder.pid                   # taken over, not refused
    lock.release()
    assert not (folder / LOCK_FILE).exists()
    with DatasetWriter(folder, rig, PANO) as writer:            # and writers work again
        writer.request(1)
        writer.write(synthetic_sample(rig, 0))
    assert len(DatasetReader(folder)) == 1 and not (folder / LOCK_FILE).exists()


def test_run_folder_and_bundle_have_one_writer(tmp_path, capsys):
    from flax import nnx

    from gijax.train.bundle import save_bundle
    from test_train_faults import CHILD

    child = {"__name__": "train_child"}
    exec(compile(CHILD, "train_child", "exec"), child)          # make_trainer, not its main
    run = tmp_path / "run"
    run.mkdir()
    holder = _hold_lock(run)
    try:
        with pytest.raises(FolderLockedError, match=re.escape(f"run folder {run} ") + f".*PID {holder.pid}"):
            child["make_trainer"](run, 2)
        assert os.listdir(run) == [LOCK_FILE]                    # no config written
    finally:
        _kill(holder)

    bundle = tmp_path / "bundle"
    config = tmp_path / "config.json"
    config.write_text("{}")
    lock_file = tmp_path / ".bundle.gijax.lock"
    holder = _hold_lock(bundle, lock_file)
    try:
        with pytest.raises(FolderLockedError, match=re.escape(f"bundle {bundle} ") + f".*PID {holder.pid}"):
            save_bundle(nnx.Linear(2, 2, rngs=nnx.Rngs(0)), config, bundle)
        assert not bundle.exists()
    finally:
        _kill(holder)
    assert save_bundle(nnx.Linear(2, 2, rngs=nnx.Rngs(0)), config, bundle) == bundle
    assert not lock_file.exists()


# ------------------------------------------------------------------ 2, 3: damaged checkpoints

def test_damaged_checkpoint_falls_back_quietly_and_eval_changes_nothing(script, tmp_path,
                                                                        caplog, recwarn):
    from gijax.store import load_for_inference

    run = tmp_path / "run"
    r = run_child(script, run, "--steps", "4", cache=CACHE)
    assert r.returncode == 0, r.stderr[-3000:]
    data = run / "checkpoints" / "4" / "state"
    largest = max((p for p in data.rglob("*") if p.is_file() and "/d/" in str(p)),
                  key=lambda p: p.stat().st_size)
    largest.write_bytes(largest.read_bytes()[:1000])
    before = _snapshot(run)

    caplog.set_level(logging.DEBUG)
    model, _, cand = load_for_inference(run, which="latest")
    np.testing.assert_allclose(np.asarray(cand), G8, rtol=1e-6)
    # One warning naming the checkpoint; no logged tracebacks of the cancelled reads.
    warned = [str(w.message) for w in recwarn if "unreadable" in str(w.message)]
    assert len(warned) == 1 and "checkpoints/4" in warned[0] and "skipping" in warned[0]
    assert "\n" not in warned[0] and len(warned[0]) < 600
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.text[:2000]
    # Evaluation reads the run folder only: nothing moved, created or deleted.
    assert _snapshot(run) == before

    # Resuming training moves it aside, still with a short stderr, and trains on from step 2.
    r = run_child(script, run, "--steps", "6", cache=CACHE)
    assert r.returncode == 0, r.stderr[-3000:]
    assert len(r.stderr) < 2000 and "Traceback" not in r.stderr, r.stderr[:3000]
    assert "moved to" in r.stderr and (run / "corrupt" / "checkpoints-4").is_dir()


# ------------------------------------------------------------------ 4: wrong kinds of paths

def test_output_paths_of_the_wrong_kind_give_one_line(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    cases = [
        (["predict", "--preset", "G16VV-cpu", "--rig", "paper-train", "--images", "a.png",
          "b.png", "c.png", "--out", str(afile)], "is an existing file, not a folder"),
        (["predict", "--preset", "G16VV-cpu", "--rig", "paper-train", "--images", "a.png",
          "b.png", "c.png", "--out", str(afile / "sub")], f"{afile} is a file"),
        (["render", "--rig", "paper-train", "--samples", "2", "--out", str(afile)],
         "is an existing file, not a folder"),
        (["train", "--preset", "G16VV-cpu", "--data", str(tmp_path), "--out", str(afile)],
         "is an existing file, not a folder"),
        (["eval", "--ckpt", str(tmp_path / "nothing"), "--data", str(tmp_path), "--json",
          str(tmp_path)], "--json"),
    ]
    for argv, expected in cases:
        assert main(argv) == 1, argv
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and expected in err, (argv, err)
    assert sorted(os.listdir(tmp_path)) == ["afile"]          # nothing made, nothing left


def test_atomic_json_into_a_folder_leaves_no_temporary(tmp_path):
    from gijax.train.config import write_json_atomic

    target = tmp_path / "DIR"
    target.mkdir()
    with pytest.raises(IsADirectoryError):
        write_json_atomic(target, {"a": 1})
    assert sorted(os.listdir(tmp_path)) == ["DIR"]


# ------------------------------------------------------------------ 5: invalid pixels

def _fake_result(valid):
    h, w = valid.shape
    dist = np.linspace(1.0, 3.0, h * w, dtype=np.float32).reshape(h, w)
    return {"distance": dist, "inv_distance": 1.0 / dist, "valid": valid,
            "entropy": np.full((h, w), 0.5, np.float32), "candidates": np.asarray(G8),
            "colour": np.full((h, w, 3), 0.5, np.float32)}


def test_prediction_files_mark_invalid_pixels(tmp_path):
    from gijax.geometry.layouts import builtin_rig
    from gijax.predict import write_prediction

    valid = np.zeros((16, 64), bool)
    valid[:, :20] = True
    result = _fake_result(valid)
    paths = write_prediction(result, builtin_rig("paper-train"), tmp_path / "p")
    dist = np.load(paths["distance"])
    assert np.isnan(dist[:, 20:]).all()
    np.testing.assert_array_equal(dist[:, :20], result["distance"][:, :20])
    np.testing.assert_array_equal(np.load(paths["valid"]), valid)
    png = cv2.imread(paths["valid_png"], cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint8 and set(np.unique(png[:, :20])) == {255}
    assert set(np.unique(png[:, 20:])) == {0}
    meta = json.loads(Path(paths["meta"]).read_text())
    assert meta["valid_pixels"] == 16 * 20 and meta["points"] == 16 * 20
    assert meta["valid_fraction"] == pytest.approx(20 / 64)
    assert "NaN" in meta["invalid_pixels"]


def _rtss_without_views(rig, sample, preset_name="RS-E32", candidates=None, pano=None):
    """RTSS's result where no pixel is seen by a camera pair (NaN, as rtss_predict documents);
    stands in for the baseline, whose own masking is tested in test_rtss.py."""
    shape = (160, 640) if pano is None else pano.shape
    nan = np.full(shape, np.nan, np.float32)
    return {"inv_distance": nan, "distance": nan, "valid": np.zeros(shape, bool)}


@pytest.mark.usefixtures("quick_compiles")
@pytest.mark.parametrize("method", ["learned", "rtss"])
def test_all_masked_prediction_is_invalid_everywhere(method, tmp_path, capsys, monkeypatch):
    import gijax.baseline.rtss

    from test_predict import TINY

    monkeypatch.setattr(gijax.baseline.rtss, "rtss_predict_sample", _rtss_without_views)

    files, masks = [], []
    for i in range(3):
        files.append(str(tmp_path / f"cam{i}.png"))
        cv2.imwrite(files[-1], np.full((64, 64, 3), 60 * (i + 1), np.uint8))
        masks.append(str(tmp_path / f"mask{i}.png"))
        cv2.imwrite(masks[-1], np.zeros((64, 64), np.uint8))
    cfg = tmp_path / "tiny.json"
    cfg.write_text(json.dumps(dataclasses.asdict(TINY)))
    out = tmp_path / "out"
    extra = (["--preset", str(cfg)] if method == "learned" else
             ["--method", "rtss", "--rtss-preset", "RS-E16"])
    assert main(["predict", *extra, "--rig", "paper-train", "--images", *files, "--masks",
                 *masks, "--out", str(out)]) == 0
    assert "no valid pixel" in capsys.readouterr().out
    dist = np.load(out / "distance.npy")
    assert dist.size and np.isnan(dist).all()
    assert not np.load(out / "valid.npy").any()
    assert cv2.imread(str(out / "valid.png"), cv2.IMREAD_UNCHANGED).max() == 0
    meta = json.loads((out / "prediction.json").read_text())
    assert meta["valid_fraction"] == 0.0 and meta["valid_pixels"] == 0 and meta["points"] == 0


# ------------------------------------------------------------------ 6: incomplete datasets

def test_interrupted_dataset_is_refused_until_accepted(rig, tmp_path, capsys):
    root = tmp_path / "partial"
    with DatasetWriter(root, rig, PANO) as writer:
        writer.request(24)
        for i in range(4):
            writer.write(synthetic_sample(rig, i))
    assert json.loads((root / "manifest.json").read_text())["requested_samples"] == 24
    run = tmp_path / "run"
    assert main(["train", "--preset", "E8-cpu", "--data", str(root), "--out", str(run),
                 "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "4 of the 24 samples" in err
    assert "--allow-partial" in err and not run.exists()
    with pytest.warns(UserWarning, match="4 of the 24"):
        assert len(DatasetReader(root, allow_partial=True)) == 4
    assert main(["data", "check", str(root), "--no-progress"]) == 1
    assert "INCOMPLETE" in capsys.readouterr().out
    assert main(["data", "check", str(root), "--no-progress", "--allow-partial"]) == 0
    # Asking for what it holds accepts it as it is.
    with DatasetWriter(root, rig, PANO) as writer:
        writer.request(4)
    assert len(DatasetReader(root)) == 4


# ------------------------------------------------------------------ 7: bad candidate list

def test_bad_candidate_list_leaves_no_run_folder(dataset, tmp_path, capsys):
    cand = tmp_path / "cand.json"
    cand.write_text(json.dumps(G8[::-1]))                     # descending: invalid
    run = tmp_path / "run"
    assert main(["train", "--preset", "E8-cpu", "--data", str(dataset), "--out", str(run),
                 "--candidates", str(cand), "--no-progress", "--batch", "2"]) == 1
    err = capsys.readouterr().err
    assert "strictly ascending" in err and len(err.strip().splitlines()) == 1
    assert not run.exists()


# ------------------------------------------------------------------ 8: damaged PNG

def _damage(path: Path) -> None:
    """Flip bytes in the middle of a PNG, keeping its size and end chunk."""
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 4] = bytes(b ^ 0xFF for b in data[mid:mid + 4])
    path.write_bytes(bytes(data))


def test_damaged_png_is_found_before_training(dataset, tmp_path, capfd):
    root = _copy(dataset, tmp_path / "data")
    bad = root / "traj_0000" / "cam1" / "rgb" / "000003.png"
    _damage(bad)
    with pytest.raises(ValueError, match="CRC mismatch"):
        pngio.read_rgb(bad)
    run = tmp_path / "run"
    assert main(["train", "--preset", "E8-cpu", "--data", str(root), "--out", str(run),
                 "--no-progress", "--batch", "2"]) == 1
    err = capfd.readouterr().err
    assert "libpng" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and str(bad) in lines[0] and "gijax data check" in lines[0], err
    assert not run.exists()
    assert main(["data", "check", str(root), "--no-progress"]) == 1
    out = capfd.readouterr()
    assert str(bad) in out.out and "1 problem(s)" in out.out and "libpng" not in out.err
    assert main(["data", "check", str(dataset), "--no-progress"]) == 0
    assert "4 samples of 4 requested, 40 files checked: OK" in capfd.readouterr().out


# ------------------------------------------------------------------ 9: logs after a resume

def test_logs_keep_one_record_per_step_after_a_resume(tmp_path):
    from gijax.io.events import EventWriter, read_events
    from gijax.train.logbook import METRICS_FILE, drop_logs_after

    run = tmp_path / "run"
    run.mkdir()
    records = [{"step": s, "loss": 1.0 / s} for s in range(1, 6)]
    records.insert(3, {"step": 3, "split": "val", "mae": 0.2})
    text = "".join(json.dumps(r) + "\n" for r in records) + '{"step": 6, "lo'   # cut short
    (run / METRICS_FILE).write_text(text)
    tb = EventWriter(run / "tb")
    for s in range(1, 6):
        tb.scalars(s, {"train/loss": 1.0 / s})
    tb.close()
    with open(tb.path, "ab") as f:
        f.write(b"\x10\x00")                                   # a frame cut short by a kill

    drop_logs_after(run, 3)
    kept = [json.loads(line) for line in (run / METRICS_FILE).read_text().splitlines()]
    assert [(r["step"], r.get("split")) for r in kept] == [(1, None), (2, None), (3, None),
                                                           (3, "val")]
    steps = [e.step for e in read_events(tb.path)]
    assert steps == [0, 1, 2, 3]                               # file header, then steps 1-3
