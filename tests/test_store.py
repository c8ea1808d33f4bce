"""Reading trained models (gijax.store): run folders (best / latest checkpoint, shape checks,
read-only), bundled models by name, and every --ckpt's error when a name matches nothing."""

import dataclasses
import json

import jax
import numpy as np
import pytest
from flax import nnx

from gijax.cli import main
from gijax.model import create_model
from gijax.store import load_model, resolve_model_path
from gijax.store.assets import ASSETS, bundled_names
from gijax.store.configs import model_config_from_dict
from gijax.train import step as S
from gijax.store.checkpoints import CheckpointStore
from gijax.train.config import TrainConfig, save_run_config

TINY = dict(feature_blocks=[1, 1], unet_base=8, feature_channels=4, unet_in=4)
CAND = np.geomspace(0.5, 100.0, 16)


def _snapshot(folder):
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in sorted(folder.rglob("*"))}


def _params_of(model):
    return [np.asarray(x) for x in jax.tree.leaves(nnx.state(model, nnx.Param))]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A run folder with periodic checkpoints at steps 1 and 2 and a best one at step 1, each
    holding distinct parameters (the initial ones times 2, 3 and 5 plus a step offset)."""
    folder = tmp_path_factory.mktemp("store") / "run"
    cfg = TrainConfig(preset="G16V-released-cpu", model_overrides=TINY, seed=4)
    model = create_model(cfg.model_config(), 4)
    _, _, params, rest = S.split_model(model)
    folder.mkdir()
    save_run_config(folder, cfg, CAND, rig_name="paper-train")
    tx = S.make_optimizer(cfg)
    store = CheckpointStore(folder, keep=2, best_metric="mae")
    saved = {}
    for step, factor in ((1, 2.0), (2, 3.0)):
        p = jax.tree.map(lambda x: x * factor + step, params)
        store.save(step, S.init_state(p, rest, tx), {"step": step})
        saved[("latest", step)] = [np.asarray(x) for x in jax.tree.leaves(p)]
    best = jax.tree.map(lambda x: x * 5.0 - 1.0, params)
    store.maybe_save_best(1, S.init_state(best, rest, tx), {"step": 1}, {"mae": 0.5})
    saved["best"] = [np.asarray(x) for x in jax.tree.leaves(best)]
    store.close()
    return {"folder": folder, "cfg": cfg, "saved": saved}


def test_run_folder_best_and_latest_restore_exactly_and_read_only(run):
    folder = run["folder"]
    before = _snapshot(folder)
    model, mc, cand = load_model(folder)
    assert mc == run["cfg"].model_config()
    assert cand.dtype == np.float64
    np.testing.assert_array_equal(cand, CAND)
    for got, want in zip(_params_of(model), run["saved"]["best"], strict=True):
        np.testing.assert_array_equal(got, want)
    latest, _, _ = load_model(folder, which="latest")
    for got, want in zip(_params_of(latest), run["saved"][("latest", 2)], strict=True):
        np.testing.assert_array_equal(got, want)
    assert _snapshot(folder) == before            # reading changes nothing in the run folder
    with pytest.raises(ValueError, match="which must be one of"):
        load_model(folder, which="newest")


def test_reads_keep_sigint_as_python_has_it_and_asyncio_never_swaps_it(run, monkeypatch):
    """orbax's asyncio.run calls would swap the SIGINT handler around each read (formatting the
    repr of a task holding the arrays each time); the store installs a plain handler for the
    duration instead: asyncio never calls signal.signal, Ctrl-C still raises
    KeyboardInterrupt, and Python's default handler is back afterwards."""
    import signal
    import threading

    from gijax.store import checkpoints as ckpt

    outer = signal.signal(signal.SIGINT, signal.default_int_handler)   # as in a plain script
    try:
        installed = []
        real = signal.signal
        monkeypatch.setattr(signal, "signal", lambda sig, h: installed.append(h) or real(sig, h))
        load_model(run["folder"])
        monkeypatch.undo()
        # Only the store's own swap (in and out, per orbax call), never asyncio's handler.
        assert installed and set(map(id, installed)) <= {id(ckpt._keyboard_interrupt),
                                                         id(signal.default_int_handler)}
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        with ckpt.plain_sigint():
            with pytest.raises(KeyboardInterrupt):
                signal.getsignal(signal.SIGINT)(signal.SIGINT, None)
        worker = threading.Thread(target=lambda: ckpt.plain_sigint().__enter__())
        worker.start()
        worker.join()                             # off the main thread: nothing is touched
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, outer)


def test_checkpoint_of_another_configuration_is_named_not_skipped(run, tmp_path):
    folder = tmp_path / "other"
    folder.mkdir()
    cfg = run["cfg"]
    with pytest.raises(FileNotFoundError, match="no run configuration"):
        load_model(folder)
    save_run_config(folder, cfg, CAND)
    with pytest.raises(FileNotFoundError, match="holds no checkpoint"):
        load_model(folder)
    # Weights of a wider U-Net under this config.json: one error naming the parameter and both
    # shapes, not a warning about a damaged checkpoint.
    wider = dataclasses.replace(cfg.model_config(), unet_base=16)
    _, _, params, rest = S.split_model(create_model(wider))
    store = CheckpointStore(folder, keep=1, best_metric=None)
    store.save(1, S.init_state(params, rest, S.make_optimizer(cfg)), {"step": 1})
    store.close()
    with pytest.raises(ValueError, match=r"has shape \(.*\) in the checkpoint but config.json"):
        load_model(folder)


def test_bundled_models_by_name_and_path_precedence(tmp_path, monkeypatch):
    names = bundled_names()
    assert "G16VV-cpu" in names
    assert resolve_model_path("G16VV-cpu") == ASSETS / "G16VV-cpu"
    monkeypatch.chdir(tmp_path)
    (tmp_path / "G16VV-cpu").mkdir()              # a path that exists wins over the name
    assert resolve_model_path("G16VV-cpu").resolve() == (tmp_path / "G16VV-cpu").resolve()
    with pytest.raises(FileNotFoundError, match="bundled models: .*G16VV-cpu"):
        resolve_model_path("no-such-model")


def test_models_command_lists_preset_parameters_and_training_data(capsys):
    assert main(["models", "--json"]) == 0
    listed = {m["name"]: m for m in json.loads(capsys.readouterr().out)}
    m = listed["G16VV-cpu"]
    config = json.loads((ASSETS / "G16VV-cpu" / "config.json").read_text())
    prov = json.loads((ASSETS / "G16VV-cpu" / "PROVENANCE.json").read_text())
    assert m["preset"] == config["model"]["name"] == "G16VV-cpu"
    # The count of a concretely built network's parameters.
    eager = create_model(model_config_from_dict(config["model"]), 0)
    assert m["parameters"] == sum(x.size for x in _params_of(eager)) > 100_000
    # What the bundle states of its training, listed as it states it.
    assert m["trained_on"] == prov["trained_on"] and "rendered" in m["trained_on"]
    # How it compares: its recorded paper-test1 figure beside RS-E32's, as recorded.
    first = prov["targets"][0]
    assert first["test"] == "paper-test1"
    assert (f"paper-test1 {first['numbers']['model']:.4f} vs RS-E32 "
            f"{first['numbers']['RS-E32']:.4f}") in m["compared"]
    assert main(["models"]) == 0
    text = capsys.readouterr().out
    assert "G16VV-cpu" in text and f"{m['parameters']:,}" in text


def test_every_ckpt_names_the_bundled_models_when_nothing_matches(tmp_path, capsys):
    import cv2

    images = []
    for i in range(3):
        images.append(str(tmp_path / f"c{i}.png"))
        cv2.imwrite(images[-1], np.zeros((8, 8, 3), np.uint8))
    commands = [
        ["predict", "--ckpt", "no-such-model", "--rig", "paper-train", "--images", *images,
         "--out", str(tmp_path / "pred")],
        ["export", "--ckpt", "no-such-model", "--rig", "paper-train", "--out",
         str(tmp_path / "m.onnx")],
        ["eval", "--ckpt", "no-such-model", "--data", str(tmp_path / "data")],
        ["demo", "--ckpt", "no-such-model", "--out", str(tmp_path / "demo")],
    ]
    for argv in commands:
        capsys.readouterr()
        assert main(argv) == 1, argv
        err = capsys.readouterr().err
        assert "no-such-model" in err and "bundled models: G16VV-cpu" in err, (argv, err)
        assert len(err.strip().splitlines()) == 1, err


def test_demo_and_models_say_what_a_bundle_was_trained_on_and_where_it_fails(tmp_path):
    """A bundle's stated training data, held-out comparison and limits are what the demo prints
    under its table; older provenance without them falls back to its data block, 'not
    recorded' and 'not stated'; a target without a model and a baseline figure is left out; a
    run folder is named as such."""
    from gijax.demo import model_note
    from gijax.store.assets import held_out_comparison, limitations, trained_on

    stated = {"trained_on": "4,800 rendered scenes on 8 rigs", "limitations": "real images",
              "data": {"train_samples": 400, "rig": "paper-train"},
              "targets": [
                  {"test": "paper-test1", "target": "MAE <= 0.75 x RS-E32", "status": "MISSED",
                   "numbers": {"model": 0.02204, "RS-E32": 0.02338, "ratio": 0.9426}},
                  {"test": "ring", "target": "spacing MAE < RS-E32", "status": "MET",
                   "numbers": {"model_spacing": 0.0228, "model_train": 0.0235,
                               "RS-E32": 0.03616}},
                  {"test": "broken", "numbers": {"ratio": 1.0}}]}
    bundle = tmp_path / "b"
    bundle.mkdir()
    (bundle / "weights.npz").write_bytes(b"")
    (bundle / "PROVENANCE.json").write_text(json.dumps(stated))
    assert model_note(bundle, "G16VV-cpu") == (
        "model G16VV-cpu: trained on 4,800 rendered scenes on 8 rigs\n"
        "compared with classical stereo: held-out MAE (1/m, the paper's definition): "
        "paper-test1 0.0220 vs RS-E32 0.0234 (MAE <= 0.75 x RS-E32: missed); "
        "ring 0.0228 vs RS-E32 0.0362 (spacing MAE < RS-E32: met)\n"
        "expected to fail on: real images")
    old = {"data": {"train_samples": 400, "rig": "paper-train", "style": "mixed"}}
    assert trained_on(old) == "400 rendered mixed scenes on paper-train"
    assert limitations(old) == "not stated" and limitations({"limitations": 3}) == "not stated"
    assert held_out_comparison(old) == "not recorded"
    assert held_out_comparison({"targets": [{"numbers": {"model": 0.1}}]}) == "not recorded"
    assert held_out_comparison({"targets": [{"numbers": {"model": 0.1, "RS-E32": "n/a"}}]}) \
        == "not recorded"
    (tmp_path / "run").mkdir()
    assert model_note(tmp_path / "run", "E8-cpu") == f"model E8-cpu: the training run {tmp_path / 'run'}"


def test_a_bundle_that_departs_from_its_preset_says_where():
    """A fine-tune may change the network's settings (the cost volume's grid, say) while its
    configuration keeps the preset's name; ``gijax models`` names the settings that differ,
    and none for a configuration equal to its preset or named after no preset."""
    from gijax.nn.presets import get_preset
    from gijax.store.assets import preset_changes

    base = get_preset("G16VV-cpu-zncc")
    assert preset_changes(base) == {}
    finer = dataclasses.replace(base, cost_hw=(32, 128), output_stride=1)
    assert preset_changes(finer) == {"cost_hw": (32, 128), "output_stride": 1}
    assert preset_changes(dataclasses.replace(finer, name="my-own-net")) == {}
