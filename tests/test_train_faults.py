"""Fault tolerance: SIGKILL mid-run and mid-save, resume, identical losses step for step."""

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

from gijax.io.events import read_events

ROOT = Path(__file__).resolve().parents[1]

# A self-contained training script: a tiny network on in-memory samples, checkpoints every 2
# steps. ``--die-in-save N`` makes the process SIGKILL itself inside orbax's commit of step N
# (after the files are written, before the atomic rename): a kill in the middle of a save.
CHILD = r'''
import argparse, os, signal, sys
import numpy as np

TINY = dict(feature_channels=4, unet_in=12, unet_base=8, feature_blocks=(1, 1),
            surrogate_hw=(32, 128), cost_hw=(8, 32), output_hw=(16, 64))
CANDIDATES = [0.5, 0.60103325, 0.73863074, 0.94007016, 1.26849604, 1.91086214, 3.77357055, 100.0]


def tiny_arrays(n=6, seed=0):
    rng = np.random.default_rng(seed)
    images = rng.uniform(0, 1, (n, 3, 32, 128, 3)).astype(np.float32)
    cols = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    rows = np.linspace(0, 1, 16)[:, None]
    dist = np.stack([1.0 + 0.6 * np.sin(cols + k) * rows + 0.2 * k for k in range(n)])
    return {"surrogates": images, "masks": np.ones((n, 3, 32, 128), np.float32),
            "distance": dist.astype(np.float32), "valid": np.ones((n, 16, 64), bool)}


def tiny_rig():
    from gijax.geometry.layouts import _triangle, layout_rig
    p = _triangle(0.3095015413531889)
    return layout_rig(p, p[0], masks=False)


def make_trainer(run, steps, ckpt_every=2, keep=2, lr=1e-3, batch=2, preset="E8-cpu"):
    from gijax.train.config import TrainConfig
    from gijax.train.sources import array_stream_factory
    from gijax.train.trainer import Trainer
    cfg = TrainConfig(preset=preset, model_overrides=TINY, lr=lr, batch_size=batch, steps=steps,
                      ckpt_every=ckpt_every, keep=keep, val_every=0, keep_best=False,
                      candidates=CANDIDATES, seed=0)
    return Trainer(cfg, run, tiny_rig(), array_stream_factory(tiny_arrays(), batch, cfg.seed),
                   progress=False)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("run"); ap.add_argument("--steps", type=int, default=6)
    ap.add_argument("--die-in-save", type=int, default=-1)
    a = ap.parse_args()
    if a.die_in_save >= 0:
        from orbax.checkpoint._src.path import atomicity
        original = atomicity.AtomicRenameTemporaryPath.finalize
        async def finalize(self, *args, **kw):
            if self.get_final().name == str(a.die_in_save):
                os.kill(os.getpid(), signal.SIGKILL)
            return await original(self, *args, **kw)
        atomicity.AtomicRenameTemporaryPath.finalize = finalize
    trainer = make_trainer(a.run, a.steps)
    trainer.fit()
    trainer.close()
'''


# The compile cache the subprocess tests share with each other and with test_train.py.
CACHE = Path(os.environ.get("GIJAX_TEST_JAX_CACHE", "/tmp/gijax-test-jax-cache"))


def child_env(cache_dir, optimised=False):
    """The environment of a child process: this checkout importable, the shared compile cache,
    CPU only, and (unless ``optimised``) no XLA optimisation passes."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    env["JAX_COMPILATION_CACHE_DIR"] = str(cache_dir)
    env["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
    env["JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES"] = "0"
    # Children that run at the same time (the two processes of a distributed run) compile the
    # same programs into the same folder, and JAX writes an entry in place: a size limit turns
    # on JAX's file lock around every read and write, so none reads a half-written entry.
    env["JAX_COMPILATION_CACHE_MAX_SIZE"] = str(8 << 30)
    env["JAX_PLATFORMS"] = "cpu"
    # Training children check orchestration (checkpoints, kills, resumes, sharding) against
    # other children, so they compile without XLA's optimisation passes, 2-3x faster; the
    # numerics of the optimised train step are checked in-process (test_train.py). Renders
    # keep the passes: unoptimised, the renderer runs about 4x slower.
    env["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "0" if optimised else "1"
    return env


def losses(run: Path) -> dict:
    """step -> list of logged losses, in log order (one each, unless a resume repeated one)."""
    out: dict = {}
    for line in (run / "metrics.jsonl").read_text().splitlines():
        rec = json.loads(line)
        if "loss" in rec:
            out.setdefault(rec["step"], []).append(rec["loss"])
    return out


def kill_when(proc: subprocess.Popen, ready, rng: random.Random, jitter: float,
              timeout: float = 240) -> bool:
    """SIGKILL ``proc`` a random moment (0 to ``jitter`` s) after ``ready()`` first holds;
    False when the process ended before that (the probe point was missed)."""
    deadline = time.time() + timeout
    while time.time() < deadline and proc.poll() is None and not ready():
        time.sleep(0.01)
    time.sleep(rng.uniform(0.0, jitter))
    if proc.poll() is not None:
        return False
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    return True


def tb_loss_steps(run: Path) -> list[int]:
    """The steps of every ``train/loss`` scalar in the run's TensorBoard files."""
    steps = []
    for path in sorted((run / "tb").glob("events.out.tfevents.*")):
        for event in read_events(path):
            if any(v.tag == "train/loss" for v in event.summary.value):
                steps.append(event.step)
    return steps


@pytest.fixture(scope="module")
def script(tmp_path_factory):
    d = tmp_path_factory.mktemp("child")
    path = d / "train_child.py"
    path.write_text(CHILD)
    return path


def run_child(script, run, *extra, cache, timeout=240):
    return subprocess.run([sys.executable, str(script), str(run), *extra], env=child_env(cache),
                          capture_output=True, text=True, timeout=timeout)


def test_kill_resume_matches_uninterrupted(script, tmp_path):
    cache = CACHE
    ref_run, run = tmp_path / "ref", tmp_path / "run"
    ref = run_child(script, ref_run, cache=cache)
    assert ref.returncode == 0, ref.stderr[-3000:]
    ref_losses = losses(ref_run)
    assert sorted(ref_losses) == [1, 2, 3, 4, 5, 6]

    # 1) SIGKILL from outside a random moment (0-50 ms) after step 3 is logged: mid-run,
    #    possibly while saving step 4 (the fault probe in test_faults.py draws other moments
    #    in its nightly variants).
    proc = subprocess.Popen([sys.executable, str(script), str(run)], env=child_env(cache),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    ready = lambda: (run / "metrics.jsonl").exists() and 3 in losses(run)  # noqa: E731
    assert kill_when(proc, ready, random.Random(0), jitter=0.05), \
        "the run finished before it could be killed"
    assert proc.returncode == -signal.SIGKILL
    assert (run / "checkpoints" / "2").is_dir()          # the last good checkpoint survives

    # 2) resume, and die inside the commit of step 6's checkpoint
    r = run_child(script, run, "--die-in-save", "6", cache=cache)
    assert r.returncode == -signal.SIGKILL, r.stderr[-3000:]
    ckpts = os.listdir(run / "checkpoints")
    assert any(n.startswith("6.orbax-checkpoint-tmp") for n in ckpts), ckpts   # half-written
    assert "6" not in ckpts and "4" in ckpts                                    # 4 is intact

    # 3) corrupt the newest complete checkpoint (4), then resume: the run warns, falls back
    #    to step 2 and trains to the end
    for f in (run / "checkpoints" / "4" / "state").rglob("*"):
        if f.is_file() and f.stat().st_size > 0 and "manifest" in f.name:
            f.write_bytes(b"\0" * 7)
    r = run_child(script, run, cache=cache)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "unreadable" in r.stderr and "falling back" in r.stderr, r.stderr[-2000:]
    assert (run / "corrupt" / "checkpoints-4").is_dir()
    got = losses(run)
    assert sorted(got) == [1, 2, 3, 4, 5, 6]
    for step, values in got.items():
        # one record per step: a resume drops what the killed run logged after its checkpoint
        assert len(values) == 1, (step, values)
        np.testing.assert_allclose(values, ref_losses[step][0], rtol=1e-6, atol=0)
    # TensorBoard's log too: every step's loss exactly once across the three resumes.
    assert tb_loss_steps(run) == [1, 2, 3, 4, 5, 6]
    resumed = [json.loads(line)["step"] for line in (run / "metrics.jsonl").read_text().splitlines()
               if "resumed" in line]
    # Steps were redone: the last resume started from step 2 (an earlier one from 2 or 4; a
    # resume event of a step later than a resume's checkpoint is dropped with that step).
    assert resumed[-1] == 2 and len(resumed) in (1, 2), resumed
    assert sorted(os.listdir(run / "checkpoints")) == ["4", "6"]       # no leftovers
