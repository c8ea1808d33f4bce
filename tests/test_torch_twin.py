"""The PyTorch twin (gijax.bench.torch_twin) computes gijax's network.

Two independent references: the authors' released network (its outputs on random weights and
inputs, ``../shared/fixtures/release/``), which the twin must reproduce from the released state
dict as it is; and gijax's JAX forward and training step on the twin's own random weights,
moved into gijax through the release weight import, with gijax's sweep grids exported to the
twin as the benchmark exports them. torch is not a dependency of gijax: without it every test
here is skipped.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

try:
    import torch
except ImportError:
    torch = None

pytestmark = pytest.mark.skipif(
    torch is None, reason="torch is not installed (the PyTorch twin is a benchmark peer only)")

FIXTURES = Path(os.environ.get(
    "GIJAX_RELEASE_FIXTURES",
    Path(__file__).resolve().parents[1].parent / "shared" / "fixtures" / "release"))
TOL = 1e-5


def rel_err(found, expected) -> float:
    found = found.detach().numpy() if torch is not None and torch.is_tensor(found) else found
    expected = np.asarray(expected, np.float64)
    return float(np.max(np.abs(np.asarray(found, np.float64) - expected))
                 / np.max(np.abs(expected)))


def test_twin_constants_are_gijax_constants():
    from gijax.bench import torch_twin as T
    from gijax.nn import layers, release_weights
    from gijax.train import losses

    assert T.LEAKY_SLOPE == layers.LEAKY_SLOPE and T.RELEASE_BF == release_weights.RELEASE_BF
    assert T.PROB_FLOOR == losses._PROB_FLOOR and T.RELEASE_BF == losses.RELEASE_INV_SCALE


@pytest.mark.skipif(not (FIXTURES / "g16vv_small.npz").is_file(),
                    reason=f"release fixtures not found in {FIXTURES}")
@pytest.mark.parametrize("name", ["g16v_released", "concat_small", "g16vv_small"])
def test_twin_reproduces_the_release(name):
    from gijax.bench import torch_twin as T

    meta = json.loads((FIXTURES / f"{name}.json").read_text())
    with np.load(FIXTURES / f"{name}.npz") as z:
        data = {k: z[k] for k in z.files}
    sd = {k[3:]: torch.from_numpy(np.asarray(v)) for k, v in data.items() if k.startswith("sd/")}
    config = dict(name=name, num_candidates=16, loss="volume", features=meta["features"],
                  cost_volume=meta["cost_volume"], num_cameras=meta["num_cameras"],
                  feature_channels=meta["feature_channels"],
                  feature_blocks=meta["feature_blocks"], unet_in=meta["unet_in"],
                  unet_base=meta["unet_base"], surrogate_hw=meta["surrogate_hw"],
                  cost_hw=meta["cost_hw"], output_hw=meta["output_hw"],
                  spherical_taps="release", sweep_boundary="zeros", output_stride=2,
                  refine=False)
    offsets = None
    if meta["features"] == "spherical":
        h, w = meta["feature_hw"]
        offsets = np.zeros((h, w, 9, 2))        # the state dict's own buffer replaces them
    twin = T.TorchTwin(config, data["candidates"], offsets)
    twin.load_state_dict(sd, strict=True)       # the release's names, unchanged
    twin.eval()
    with torch.no_grad():
        out = twin(torch.from_numpy(data["imgs"]), torch.from_numpy(data["masks"][:, :, 0]),
                   torch.from_numpy(data["grids"][0]),
                   torch.from_numpy(data["grid_masks"][0, ..., 0]))
        labels = T.RELEASE_BF / torch.from_numpy(data["labels_bf"][:, 0])
        loss = T.model_loss(twin, out, labels, torch.ones(labels.shape, dtype=torch.bool))
    assert rel_err(out["features"], data["features"]) < TOL
    assert rel_err(out["cost_volume"], data["cost_volume"]) < TOL
    assert rel_err(out["logits"], data["costs"][:, 0]) < TOL
    assert rel_err(out["prob"], data["prob"]) < TOL
    assert rel_err(out["inv_distance"] * T.RELEASE_BF, data["inv_dist_bf"][:, 0]) < TOL
    assert abs(float(loss) - float(data["volume_loss"])) < TOL * float(data["volume_loss"])


def _tiny(preset: str):
    from gijax.nn.presets import get_preset

    return dataclasses.replace(get_preset(preset), name=preset + "-tiny", surrogate_hw=(32, 128),
                               cost_hw=(8, 32), output_hw=(16, 64))


def _random_twin(config, seed: int):
    """A twin of ``config`` with random weights and random BatchNorm statistics."""
    from gijax.bench import torch_twin as T
    from gijax.bench.torch_peer import peer_inputs

    inputs = peer_inputs(config, batch=2, seed=seed)
    # One camera of one sample blind over a third of its image: the variance cost volume
    # then drops it there.
    masks = inputs["masks"].copy()
    masks[0, 0, :, : masks.shape[-1] // 3] = 0.0
    inputs["masks"] = masks
    torch.manual_seed(seed)
    twin = T.TorchTwin(config, inputs["candidates"], inputs.get("offsets"))
    with torch.no_grad():
        for module in twin.modules():
            if isinstance(module, (torch.nn.BatchNorm2d, torch.nn.BatchNorm3d)):
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.2, 0.2)
                module.running_mean.uniform_(-0.2, 0.2)
                module.running_var.uniform_(0.5, 1.5)
    return twin, inputs


def _gijax_model(config, twin):
    from gijax.bench.torch_twin import numpy_state_dict
    from gijax.model import create_model
    from gijax.nn.release_weights import load_state_dict

    model = create_model(config, seed=1)
    load_state_dict(model, numpy_state_dict(twin), input_order="rgb")
    return model


def _torch_inputs(inputs):
    from gijax.bench.torch_twin import tensors

    x = tensors(inputs)
    return x["surrogates"], x["masks"], x["grids"], x["grid_ok"]


@pytest.mark.usefixtures("quick_compiles")
@pytest.mark.parametrize("preset", ["G16VV-cpu", "G8-cpu"])
def test_twin_matches_gijax_forward_on_the_same_weights(preset):
    """Features, cost volume, logits, probabilities, inverse distance and the preset's loss of
    an eval-mode forward agree to 1e-5 (spherical features + masked variance + volume loss;
    plain features + concat + smooth L1)."""
    from flax import nnx

    from gijax.bench.torch_twin import model_loss
    from gijax.sweep.grids import SweepGrids
    from gijax.train.losses import model_loss as gijax_loss

    config = _tiny(preset)
    twin, inputs = _random_twin(config, seed=3)
    model = _gijax_model(config, twin)
    twin.eval()
    with torch.no_grad():
        out_t = twin(*_torch_inputs(inputs))
        dist = torch.from_numpy(inputs["distance"])
        loss_t = model_loss(twin, out_t, dist, torch.from_numpy(inputs["valid"]))

    grids = SweepGrids(jnp.asarray(inputs["sweep_px"]), jnp.asarray(inputs["grid_ok"]),
                       jnp.asarray(inputs["candidates"], jnp.float32))
    sur, masks = jnp.asarray(inputs["surrogates"]), jnp.asarray(inputs["masks"])

    @nnx.jit
    def run(model, sur, masks, grids):
        feats = model.extract_features(sur)
        swept, ok = model.sweep(feats, masks, grids)
        volume = model.build_cost_volume(swept, ok)
        out = model(sur, masks, grids)
        loss = gijax_loss(config.loss, out, jnp.asarray(inputs["distance"]),
                          jnp.asarray(inputs["valid"]), grids.candidates)
        return feats, volume, out, loss, jnp.mean(ok)

    feats, volume, out, loss, seen = run(model, sur, masks, grids)
    assert rel_err(out_t["features"], np.moveaxis(np.asarray(feats), -1, 2)) < TOL
    assert rel_err(out_t["cost_volume"], np.moveaxis(np.asarray(volume), -1, 1)) < TOL
    assert rel_err(out_t["logits"], out["logits"]) < TOL
    assert rel_err(out_t["prob"], out["prob"]) < TOL
    assert rel_err(out_t["inv_distance"], out["inv_distance"]) < TOL
    assert abs(float(loss_t) - float(loss)) < TOL * float(loss)
    # The blinded part of a mask removes some cameras from some cells.
    assert 0.5 < float(seen) < 1.0


@pytest.mark.slow
def test_twin_training_step_matches_gijax_train_step():
    """One optimiser step of each framework from the same weights (train-mode BatchNorm):
    the same loss and gradient norm before the update, the same loss after it. Compiled with
    XLA's optimisations, whatever an earlier test of this module set (``quick_compiles`` lasts
    for the module): without them XLA's CPU backend reports a gradient norm 3 % off for this
    step (the feature extractor's gradients; its loss and the optimised gradient agree with
    PyTorch)."""
    previous = jax.config.read("jax_disable_most_optimizations")
    jax.config.update("jax_disable_most_optimizations", False)
    try:
        _check_training_step()
    finally:
        jax.config.update("jax_disable_most_optimizations", previous)


def _check_training_step():
    import optax

    from gijax.bench.torch_twin import train_step
    from gijax.bench.rigs import network_rig
    from gijax.geometry.layouts import builtin_rig
    from gijax.train import step as S

    config = _tiny("G16VV-cpu")
    twin, inputs = _random_twin(config, seed=5)
    model = _gijax_model(config, twin)
    rig = network_rig(builtin_rig("paper-train"), config)
    tdef, _, params, rest = S.split_model(model)
    tx = optax.adam(1e-4)
    step = jax.jit(S.build_train_step(tdef, tx, config.loss))
    state = S.init_state(params, rest, tx)
    batch = {"surrogates": jnp.asarray(inputs["surrogates"]), "masks": jnp.asarray(inputs["masks"]),
             "distance": jnp.asarray(inputs["distance"]), "valid": jnp.asarray(inputs["valid"])}
    cand = jnp.asarray(inputs["candidates"], jnp.float32)
    state, info1 = step(state, batch, rig, cand)
    _, info2 = step(state, batch, rig, cand)

    run = train_step(twin, inputs, lr=1e-4)
    loss1, norm1 = run()
    loss2, _ = run()
    assert abs(loss1 - float(info1["loss"])) < TOL * loss1
    assert abs(norm1 - float(info1["grad_norm"])) < 1e-4 * norm1
    assert abs(loss2 - float(info2["loss"])) < TOL * loss2
    assert loss2 != loss1   # the step moved the weights


def test_stand_in_samples_the_taps_deform_conv2d_samples():
    """Without torchvision the spherical layer falls back to grid_sample; on the release's
    offsets (taps off the map at the pole and the seam included) it equals torchvision's
    deform_conv2d."""
    pytest.importorskip("torchvision", reason="torchvision is not installed: nothing to compare")
    from torchvision.ops import deform_conv2d

    from gijax.bench.torch_twin import FixedOffsetConv
    from gijax.nn.spherical import release_offsets

    torch.manual_seed(0)
    conv = FixedOffsetConv(4, 5, release_offsets(8, 32))
    x = torch.randn(2, 4, 8, 32)
    expected = deform_conv2d(x, conv.offset.expand(2, -1, -1, -1), conv.weight, padding=1)
    assert rel_err(conv._stand_in(x).detach(), expected.detach().numpy()) < TOL
