"""Learned candidate lists: the parametrisation of valid lists, gradients of the adaptation
losses with respect to the list (against finite differences), an adaptation that provably
moves a bad list to a lower loss and resumes exactly, and the command line."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from hypothesis import given, settings
from hypothesis import strategies as st

from gijax.candidates import (candidates_from_logits, ev_candidates, gi_candidates,
                              logits_from_candidates, spacing_gi_candidates)
from gijax.geometry.layouts import builtin_rig
from gijax.geometry.rig import scale_rig
from gijax.model import create_model
from gijax.nn.presets import ModelConfig
from gijax.train.adapt import AdaptConfig, adapt_candidates, adaptation_loss
from gijax.model import model_rig

TINY = ModelConfig(
    name="tiny-adapt", num_candidates=8, candidates="ev", loss="volume", features="plain",
    cost_volume="variance", feature_channels=4, feature_blocks=(1, 1), unet_in=4, unet_base=4,
    surrogate_hw=(16, 64), cost_hw=(8, 32), output_hw=(16, 64), image_scale=1 / 16)


# ------------------------------------------------------------------------ parametrisation

def test_zero_logits_are_the_even_list_and_lists_round_trip():
    np.testing.assert_allclose(np.asarray(candidates_from_logits(jnp.zeros(7), 0.5, 100.0)),
                               np.asarray(ev_candidates(8, 0.5, 100.0)), rtol=1e-6)
    rig = builtin_rig("paper-test3")
    for lst in (gi_candidates(16, 0.5, 100.0), ev_candidates(8, 0.5, 100.0),
                spacing_gi_candidates(rig, 16)):
        lst = np.asarray(lst, np.float64)
        with jax.enable_x64(True):
            back = candidates_from_logits(logits_from_candidates(jnp.asarray(lst)), lst[0],
                                          lst[-1])
        np.testing.assert_allclose(np.asarray(back), lst, rtol=1e-12)
        assert abs(float(jnp.mean(logits_from_candidates(jnp.asarray(lst))))) < 1e-5


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 31), st.floats(-30.0, 30.0), st.integers(0, 2**31 - 1))
def test_every_logit_vector_is_a_valid_list(n, scale, seed):
    logits = np.random.default_rng(seed).normal(size=n) * scale
    with jax.enable_x64(True):
        c = np.asarray(candidates_from_logits(jnp.asarray(logits), 0.3, 50.0))
    assert c.shape == (n + 1,)
    assert c[0] == 0.3 and c[-1] == 50.0
    assert np.all(np.diff(c) >= 0) and np.all(np.isfinite(c))
    # Strictly increasing wherever float64 can tell the steps apart from zero.
    steps = 1 / c[:-1] - 1 / c[1:]
    np.testing.assert_allclose(steps.sum(), 1 / 0.3 - 1 / 50.0, rtol=1e-12)


def test_bad_lists_are_named():
    with pytest.raises(ValueError, match="strictly ascending"):
        logits_from_candidates(jnp.array([0.5, 2.0, 1.0, 100.0]))
    with pytest.raises(ValueError, match="keeps both ends fixed"):
        logits_from_candidates(jnp.array([0.5, 1.0, 100.0]), d_min=0.4)
    with pytest.raises(ValueError, match="shape"):
        candidates_from_logits(jnp.zeros((2, 3)))


# ------------------------------------------------------------------------ gradients

def _batch(seed=0, b=1, near=1.0, far=8.0):
    """Random surrogates, full masks and labels (``near``..``far`` m) for the 3-camera rig."""
    rng = np.random.default_rng(seed)
    hs, ws = TINY.surrogate_hw
    h, w = TINY.output_hw
    return {"surrogates": rng.uniform(0, 1, (b, 3, hs, ws, 3)),
            "masks": np.ones((b, 3, hs, ws)),
            "distance": rng.uniform(near, far, (b, h, w)),
            "valid": np.ones((b, h, w), bool)}


@pytest.fixture(scope="module")
def tiny_model():
    model = create_model(TINY, seed=3)
    model.eval()
    return model


@pytest.mark.parametrize("kind", ["supervised", "photometric"])
def test_loss_gradient_in_the_list_matches_finite_differences(tiny_model, kind, quick_compiles):
    with jax.enable_x64(True):
        graphdef, state = nnx.split(tiny_model)
        model = nnx.merge(graphdef, jax.tree.map(
            lambda x: x.astype(jnp.float64) if jnp.issubdtype(x.dtype, jnp.floating) else x,
            state))
        rig = model_rig(scale_rig(builtin_rig("paper-train"), TINY.image_scale))
        rig = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64)
                           if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating) else x, rig)
        batch = {k: jnp.asarray(v) for k, v in _batch(1).items()}
        logits = logits_from_candidates(jnp.asarray(np.asarray(gi_candidates(8, 0.5, 100.0),
                                                               np.float64)))

        graphdef, state = nnx.split(model)
        # One program for the loss and one for its gradient (eager dispatch of a whole network
        # op by op is what would take the time here).
        f = jax.jit(lambda lg: adaptation_loss(kind, nnx.merge(graphdef, state), lg, batch, rig,
                                               0.5, 100.0))
        grad = jax.jit(jax.grad(f))(logits)
        assert np.all(np.isfinite(np.asarray(grad))) and float(jnp.abs(grad).max()) > 0
        direction = jnp.asarray(np.random.default_rng(5).normal(size=logits.shape))
        eps = 1e-6
        fd = (f(logits + eps * direction) - f(logits - eps * direction)) / (2 * eps)
        np.testing.assert_allclose(float(jnp.dot(grad, direction)), float(fd), rtol=2e-4,
                                   atol=1e-9)


# ------------------------------------------------------------------------ adaptation

class FixedBatches:
    """A loader that yields the same batches in turn, with a resumable state; it can be told
    to fail after some batches (an interrupted run)."""

    def __init__(self, batches, state=None, fail_after=None):
        self.batches = batches
        self.i = 0 if state is None else state["i"]
        self.fail_after = fail_after
        self.served = 0

    def __next__(self):
        if self.fail_after is not None and self.served >= self.fail_after:
            raise KeyboardInterrupt
        out = self.batches[self.i % len(self.batches)]
        self.i += 1
        self.served += 1
        return out

    def state(self):
        return {"i": self.i}

    def close(self):
        pass


def test_adaptation_moves_a_crowded_list_to_a_lower_loss_and_resumes(tiny_model, tmp_path,
                                                                     quick_compiles):
    """Seven of eight candidates crowded near d_max while the scene is 0.6-1.5 m away: the
    soft-argmax (a probability-weighted mean of inverse candidates, at most 1/60 m^-1 from the
    seven) predicts far too far unless the network puts most of its mass on the one near
    candidate, so descent must bring the list towards the near end."""
    rig = model_rig(scale_rig(builtin_rig("paper-train"), TINY.image_scale))
    batches = [{k: np.asarray(v, np.float32) if v.dtype != bool else v
                for k, v in _batch(s, 2, 0.6, 1.5).items()} for s in range(2)]
    crowded = np.concatenate([[0.5], np.linspace(60.0, 100.0, 7)])
    cfg = AdaptConfig(loss="supervised", steps=8, lr=0.3, batch_size=2, checkpoint_every=2)
    graphdef, state = nnx.split(tiny_model)
    loss_jit = jax.jit(lambda st, lg, b: adaptation_loss(
        "supervised", nnx.merge(graphdef, st), lg, b, rig, 0.5, 100.0))

    def loss_of(cand):
        lg = logits_from_candidates(jnp.asarray(cand, jnp.float32))
        return np.mean([float(loss_jit(state, lg, {k: jnp.asarray(v) for k, v in b.items()}))
                        for b in batches])

    full = adapt_candidates(tiny_model, rig, lambda s: FixedBatches(batches, s), crowded, cfg,
                            tmp_path / "full.json", progress=False)
    assert loss_of(full.candidates) < 0.85 * loss_of(crowded)
    assert full.candidates[0] == 0.5 and full.candidates[-1] == 100.0
    assert np.all(np.diff(full.candidates) > 0)
    # The list moved towards the near end: its median candidate came closer.
    assert np.median(full.candidates) < 0.5 * np.median(crowded)

    # Interrupted after 5 batches (checkpoint at 4), then the same call again: same list.
    out = tmp_path / "cut.json"
    with pytest.raises(KeyboardInterrupt):
        adapt_candidates(tiny_model, rig, lambda s: FixedBatches(batches, s, fail_after=5),
                         crowded, cfg, out, progress=False)
    assert not out.exists()
    record = json.loads((tmp_path / "cut.adapt" / "record.json").read_text())
    assert record["step"] == 4
    notes = []
    resumed = adapt_candidates(tiny_model, rig, lambda s: FixedBatches(batches, s), crowded, cfg,
                               out, progress=False, log=notes.append)
    assert any("resuming after step 4" in n for n in notes)
    np.testing.assert_allclose(resumed.candidates, full.candidates, rtol=1e-5)
    doc = json.loads(out.read_text())
    assert len(doc["candidates"]) == 8 and doc["loss"] == "supervised"
    assert (tmp_path / "cut.adapt" / "curve.png").stat().st_size > 1000
    with pytest.raises(ValueError, match="other settings"):
        adapt_candidates(tiny_model, rig, lambda s: FixedBatches(batches, s), crowded,
                         AdaptConfig(loss="supervised", steps=8, lr=0.1, batch_size=2), out,
                         progress=False)


def test_cli_adapts_a_bundle_photometrically(tiny_model, tmp_path, capsys):
    """The command on a bundle and a dataset of its rig (synthetic images, no rendering)."""
    from gijax.cli import main
    from gijax.data import write_dataset
    from gijax.geometry.panorama import Panorama
    from gijax.store.configs import CONFIG_FILE, run_config_document
    from gijax.train.bundle import save_bundle

    cand = np.asarray(gi_candidates(8, 0.5, 100.0), np.float64)
    (tmp_path / CONFIG_FILE).write_text(json.dumps(run_config_document(
        {"seed": 3}, TINY, cand, "paper-train")))
    bundle = save_bundle(tiny_model, tmp_path / CONFIG_FILE, tmp_path / "bundle")
    rig = scale_rig(builtin_rig("paper-train"), TINY.image_scale)
    rng = np.random.default_rng(0)
    h, w = rig.cameras[0].height, rig.cameras[0].width
    write_dataset(tmp_path / "data", lambda i: {
        "images": rng.integers(0, 256, (3, h, w, 3), dtype=np.uint8),
        "distances": np.full((3, h, w), 2.0, np.float32), "masks": np.ones((3, h, w), np.uint8),
        "pano_distance": np.full(TINY.output_hw, 2.0, np.float32)},
        rig, Panorama.hemisphere(*TINY.output_hw), num_samples=2)
    out = tmp_path / "list.json"
    rc = main(["adapt-candidates", "--ckpt", str(bundle), "--data", str(tmp_path / "data"),
               "--out", str(out), "--loss", "photometric", "--steps", "2", "--batch", "1",
               "--workers", "0"])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    assert "start: training list" in printed and "adapted" in printed
    doc = json.loads(out.read_text())
    assert len(doc["candidates"]) == 8 and doc["loss"] == "photometric"
    assert doc["command"].startswith("gijax adapt-candidates") and "--loss photometric" in \
        doc["command"]
    # The list file is a candidate file for every command.
    from gijax.candidates.spec import read_candidate_file

    np.testing.assert_allclose(read_candidate_file(out), doc["candidates"])
    # A label panorama of another size than the model's output is refused, naming both.
    rc = main(["adapt-candidates", "--ckpt", "G16VV-cpu", "--data", str(tmp_path / "data"),
               "--out", str(tmp_path / "other.json")])
    assert rc == 1 and "16 x 64 panoramas but model 'G16VV-cpu' outputs 32 x 128" in \
        capsys.readouterr().err
