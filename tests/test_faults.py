"""Fault probe: SIGKILL training and rendering at random points, resume, and compare with an
uninterrupted run.

Training: the killed-and-resumed run must log every step exactly once (metrics.jsonl and the
TensorBoard events) with the losses of the uninterrupted run, and end with the same
checkpoints. Rendering: the killed dataset must read as incomplete, and the resumed one must be
byte-identical to the uninterrupted one. CI kills a render once here and a training once in
tests/test_train_faults.py (with the same checks); the ``long`` variants try more seeds of both
and run only with GIJAX_LONG_TESTS=1 (nightly).
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gijax.data.check import check_dataset
from gijax.data.reader import DatasetReader
from gijax.io.rigfile import save_rig
from test_data_format import _tree, tiny_rig
from test_train_faults import (CACHE, child_env, kill_when, losses, run_child,  # noqa: F401
                               script, tb_loss_steps)                    # (script: fixture)

STEPS = 6
SAMPLES = 40          # rendering a tiny sample takes ~0.05 s: enough of them to kill inside


@pytest.fixture(scope="module")
def reference_run(script, tmp_path_factory):
    run = tmp_path_factory.mktemp("ref") / "run"
    r = run_child(script, run, "--steps", str(STEPS), cache=CACHE)
    assert r.returncode == 0, r.stderr[-3000:]
    return run


def train_probe(script, reference_run: Path, run: Path, seed: int) -> None:
    rng = random.Random(seed)
    target = rng.randint(1, STEPS - 2)           # killed soon after this step is logged
    proc = subprocess.Popen([sys.executable, str(script), str(run), "--steps", str(STEPS)],
                            env=child_env(CACHE), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    ready = lambda: (run / "metrics.jsonl").exists() and target in losses(run)  # noqa: E731
    killed = kill_when(proc, ready, rng, jitter=0.05)
    assert killed, f"training ended before the kill after step {target}"
    r = run_child(script, run, "--steps", str(STEPS), cache=CACHE)
    assert r.returncode == 0, r.stderr[-3000:]
    ref = losses(reference_run)
    got = losses(run)
    # One record per step, with the uninterrupted run's loss.
    assert sorted(got) == list(range(1, STEPS + 1)), (seed, target, got)
    for step, values in got.items():
        assert len(values) == 1, (seed, target, step, values)
        np.testing.assert_allclose(values[0], ref[step][0], rtol=1e-6, atol=0)
    assert tb_loss_steps(run) == list(range(1, STEPS + 1)), (seed, target, killed)
    events = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert sum(e.get("event") == "resumed" for e in events) <= 1
    assert sorted(os.listdir(run / "checkpoints")) == sorted(
        os.listdir(reference_run / "checkpoints"))                 # no leftovers


def render_probe(rig_file: Path, ref: Path, out: Path, seed: int) -> None:
    rng = random.Random(1000 + seed)
    target = rng.randint(1, SAMPLES - 15)
    cmd = [sys.executable, "-m", "gijax", "render", "--rig", str(rig_file), "--samples",
           str(SAMPLES), "--out", str(out), "--seed", "3", "--pano", "32x8"]
    csv = out / "traj_0000" / "files.csv"
    proc = subprocess.Popen(cmd, env=child_env(CACHE, optimised=True),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ready = lambda: csv.exists() and len(csv.read_text().splitlines()) > target  # noqa: E731
    assert kill_when(proc, ready, rng, jitter=0.1), f"render ended before the kill ({target})"
    result = check_dataset(out)                   # a dataset that knows it is partial
    assert result.requested == SAMPLES and not result.problems
    assert target <= result.samples < SAMPLES and not result.complete
    with pytest.raises(ValueError, match=f"{result.samples} of the {SAMPLES} samples"):
        DatasetReader(out)
    r = subprocess.run(cmd, env=child_env(CACHE, optimised=True), capture_output=True,
                       text=True, timeout=240)
    assert r.returncode == 0, r.stderr[-3000:]
    assert _tree(out) == _tree(ref), seed          # byte-identical, no lock or partial left


@pytest.fixture(scope="module")
def render_reference(tmp_path_factory):
    d = tmp_path_factory.mktemp("render")
    rig_file = d / "tiny.yaml"
    save_rig(tiny_rig(), rig_file)
    ref = d / "ref"
    r = subprocess.run([sys.executable, "-m", "gijax", "render", "--rig", str(rig_file),
                        "--samples", str(SAMPLES), "--out", str(ref), "--seed", "3", "--pano",
                        "32x8"], env=child_env(CACHE, optimised=True), capture_output=True,
                       text=True, timeout=240)
    assert r.returncode == 0, r.stderr[-3000:]
    return rig_file, ref


def test_render_killed_at_a_random_point_resumes_to_the_same_bytes(render_reference, tmp_path):
    rig_file, ref = render_reference
    render_probe(rig_file, ref, tmp_path / "out", seed=0)


# The CI run's training kill is tests/test_train_faults.py's kill-and-resume test (a random
# moment after step 3, then two more faults, then the same checks); these draw other steps.
@pytest.mark.long
@pytest.mark.parametrize("seed", range(0, 6))
def test_training_fault_probe_more_seeds(script, reference_run, tmp_path, seed):
    train_probe(script, reference_run, tmp_path / "run", seed)


@pytest.mark.long
@pytest.mark.parametrize("seed", range(1, 6))
def test_render_fault_probe_more_seeds(render_reference, tmp_path, seed):
    rig_file, ref = render_reference
    render_probe(rig_file, ref, tmp_path / "out", seed)


def test_ctrl_c_during_rendering_ends_in_one_line_and_the_same_command_continues(
        render_reference, tmp_path):
    rig_file, ref = render_reference
    # A suite started in the background of a non-interactive shell runs with SIGINT ignored,
    # and children inherit that (Python then installs no KeyboardInterrupt handler): the child
    # puts Python's handler back first, as a terminal's foreground process has it, then runs
    # what ``python -m gijax`` runs.
    launcher = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
                "from gijax.cli import run; run()")
    # The whole render takes a few seconds; a test process starved by the other worker can
    # send its Ctrl-C after the last sample, when there is nothing left to interrupt. Such an
    # attempt (exit 0, every sample written) proves nothing and is made again afresh.
    for attempt in range(3):
        out = tmp_path / f"out{attempt}"
        cmd = [sys.executable, "-c", launcher, "render", "--rig", str(rig_file), "--samples",
               str(SAMPLES), "--out", str(out), "--seed", "3", "--pano", "32x8"]
        csv = out / "traj_0000" / "files.csv"
        proc = subprocess.Popen(cmd, env=child_env(CACHE, optimised=True),
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        deadline = time.time() + 240
        while time.time() < deadline and proc.poll() is None and not (
                csv.exists() and len(csv.read_text().splitlines()) > 3):
            time.sleep(0.01)
        assert proc.poll() is None, "render ended before Ctrl-C"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
        written = sum(len(f.read_text().splitlines()) - 1          # rows under each header
                      for f in out.glob("traj_*/files.csv"))
        if proc.returncode == 0 and written == SAMPLES:
            continue
        break
    assert proc.returncode == 130, err[-3000:]
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err
    assert lines[-1] == (f"gijax render: interrupted; {out} keeps the samples written so far; "
                         f"the same command continues from them")
    r = subprocess.run(cmd, env=child_env(CACHE, optimised=True), capture_output=True,
                       text=True, timeout=240)
    assert r.returncode == 0, r.stderr[-3000:]
    assert _tree(out) == _tree(ref)                # nothing lost, nothing mixed
