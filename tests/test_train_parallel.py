"""Data parallelism: 4 forced CPU devices and two processes agree with one device."""

import socket
import subprocess
import sys

import numpy as np
import pytest

from test_train_faults import CACHE, CHILD, child_env

# Runs one training step of the volume-loss variant (global batch 4) on a mesh of the given
# devices and saves the resulting state. Modes: 'devices' compares a 1-device and a 4-device mesh in one process;
# 'dist' is one of two processes joined by jax.distributed.initialize (2 devices each).
PARALLEL = CHILD.split('if __name__ == "__main__":')[0] + r'''
import jax, sys
from flax import nnx

def flat(tree):
    return np.concatenate([np.asarray(x.addressable_data(0)).ravel().astype(np.float64)
                           for x in jax.tree.leaves(tree)])

def train(run, devices):
    from gijax.train.config import TrainConfig
    from gijax.train.sources import array_stream_factory
    from gijax.train.trainer import Trainer
    cfg = TrainConfig(preset="E8-cpu", model_overrides=dict(TINY, loss="volume"), lr=1e-3,
                      batch_size=4, steps=1,
                      ckpt_every=0, val_every=0, keep_best=False, candidates=CANDIDATES)
    t = Trainer(cfg, run, tiny_rig(), array_stream_factory(tiny_arrays(8), 4, 0), progress=False,
                devices=devices)
    h = t.fit()
    t.close()
    st = t.state
    # parameters, Adam's first moment (0.1 x the gradient after one step), BatchNorm statistics
    return dict(p=flat(st["params"]), mu=flat(st["opt"][0].mu), rest=flat(st["rest"]),
                loss=[r["loss"] for r in h if "loss" in r])

mode, out = sys.argv[1], sys.argv[2]
if mode == "devices":
    assert len(jax.devices()) == 4, jax.devices()
    one = train(out + "/one", jax.devices()[:1])
    four = train(out + "/four", jax.devices())
    np.savez(out + "/one.npz", **one)
    np.savez(out + "/four.npz", **four)
else:
    from gijax.train.trainer import init_distributed
    init_distributed(sys.argv[3], 2, int(mode[-1]))
    assert jax.process_count() == 2 and len(jax.devices()) == 4
    res = train(out + "/dist", None)
    if jax.process_index() == 0:
        np.savez(out + "/dist.npz", **res)
'''


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    d = tmp_path_factory.mktemp("parallel")
    script = d / "parallel_child.py"
    script.write_text(PARALLEL)
    cache = CACHE
    env4 = child_env(cache)
    env4["XLA_FLAGS"] = env4.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4"
    r = subprocess.run([sys.executable, str(script), "devices", str(d)], env=env4,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    env2 = child_env(cache)
    env2["XLA_FLAGS"] = env2.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    addr = f"127.0.0.1:{_free_port()}"
    procs = [subprocess.Popen([sys.executable, str(script), f"dist{i}", str(d), addr], env=env2,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i in range(2)]
    try:
        outs = [p.communicate(timeout=300) for p in procs]
    except subprocess.TimeoutExpired:
        # Say where each process stood rather than only that the first one timed out.
        for p in procs:
            p.kill()
        errs = [p.communicate()[1][-1500:] for p in procs]
        pytest.fail("the two processes did not finish in 300 s:\n" + "\n---\n".join(errs))
    for p, (_, err) in zip(procs, outs):
        assert p.returncode == 0, err[-3000:]
    return {k: dict(np.load(d / f"{k}.npz")) for k in ("one", "four", "dist")}


def assert_same_step(a, b):
    """One optimiser step on the same global batch gives the same state.

    Tolerances: the sharded step sums the batch gradient and the BatchNorm statistics across
    devices in another order than one device does, so float32 rounding differs: the loss agrees
    to 1e-6 relative, gradients (Adam's first moment) and BatchNorm statistics to 1e-5 of their
    largest magnitude. Adam's first update is about lr * sign(gradient), so a parameter whose
    gradient is at rounding level may move by up to 2 lr the other way: parameters agree to
    1e-6 wherever |gradient| exceeds 1e-3 of the largest gradient (over 20 % of them), and to
    2 lr everywhere.
    """
    np.testing.assert_allclose(a["loss"], b["loss"], rtol=1e-6)
    g = np.abs(b["mu"]).max()
    np.testing.assert_allclose(a["mu"], b["mu"], rtol=0, atol=1e-5 * g)
    np.testing.assert_allclose(a["rest"], b["rest"], rtol=0, atol=1e-5 * np.abs(b["rest"]).max())
    strong = np.abs(b["mu"]) > 1e-3 * g
    assert strong.mean() > 0.2
    np.testing.assert_allclose(a["p"][strong], b["p"][strong], rtol=0, atol=1e-6)
    np.testing.assert_allclose(a["p"], b["p"], rtol=0, atol=2 * 1e-3 + 1e-6)


def test_four_devices_match_one(results):
    assert np.all(np.isfinite(results["four"]["p"]))
    assert_same_step(results["four"], results["one"])


def test_two_processes_match_one_device(results):
    assert_same_step(results["dist"], results["one"])
