"""Inference bundles: weights survive save -> load exactly, and mismatches are named."""

import dataclasses
import json

import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from gijax.model import create_model, with_estimate
from gijax.nn.presets import get_preset
from gijax.store import is_bundle, load_bundle, load_model
from gijax.store.bundles import WEIGHTS_FILE
from gijax.train.bundle import save_bundle, write_bundle
from gijax.train.config import TrainConfig, save_run_config

TINY = dict(feature_channels=4, feature_blocks=(1, 1), unet_in=4, unet_base=4,
            surrogate_hw=(32, 128), cost_hw=(8, 32), output_hw=(16, 64))


def _run_config(tmp_path, **over):
    cfg = TrainConfig(preset="G16VV-cpu", model_overrides={**TINY, **over})
    run = tmp_path / "run"
    run.mkdir()
    save_run_config(run, cfg, np.linspace(0.5, 100.0, 16), rig_name="paper-train")
    return cfg, run / "config.json"


def test_bundle_round_trip_is_exact(tmp_path):
    cfg, config_file = _run_config(tmp_path)
    model = create_model(cfg.model_config(), seed=3)
    # Make the weights differ from a fresh initialisation so a silent re-init would be caught.
    state = nnx.state(model, nnx.Param)
    state = jax_tree_scale(state, 1.5)
    nnx.update(model, state)
    out = save_bundle(model, config_file, tmp_path / "bundle", {"command": "test"})
    assert is_bundle(out) and not is_bundle(tmp_path)
    loaded, mc, cand = load_model(out)
    assert mc == cfg.model_config()
    np.testing.assert_allclose(np.asarray(cand), np.linspace(0.5, 100.0, 16), rtol=1e-6)
    want = nnx.to_pure_dict(nnx.state(model))
    got = nnx.to_pure_dict(nnx.state(loaded))
    flat_w = jnp.concatenate([jnp.ravel(x) for x in _leaves(want)])
    flat_g = jnp.concatenate([jnp.ravel(x) for x in _leaves(got)])
    assert flat_w.shape == flat_g.shape and flat_w.size > 1000
    np.testing.assert_array_equal(np.asarray(flat_w), np.asarray(flat_g))
    assert json.loads((out / "PROVENANCE.json").read_text()) == {"command": "test"}


def test_a_bundle_written_with_another_estimate_reads_the_same_weights_so(tmp_path):
    """``estimate='mode'`` writes the run's network read by its sub-pixel mode: the same
    weights byte for byte, the configuration's estimate replaced (nothing else), the loaded
    model reads by the mode (a prediction of the network's own probabilities checked against
    the mode computed from them); a wrong estimate is refused before anything is written."""
    from gijax.nn.regressor import estimate_inverse

    cfg, config_file = _run_config(tmp_path)
    model = create_model(cfg.model_config(), seed=3)
    plain = save_bundle(model, config_file, tmp_path / "plain")
    mode = save_bundle(model, config_file, tmp_path / "mode", estimate="mode")
    assert (plain / WEIGHTS_FILE).read_bytes() == (mode / WEIGHTS_FILE).read_bytes()
    a, b = (json.loads((p / "config.json").read_text()) for p in (plain, mode))
    assert b["model"].pop("estimate") == "mode" and a["model"].pop("estimate", "mean") == "mean"
    assert a == b
    loaded, mc, cand = load_model(mode)
    assert mc == dataclasses.replace(cfg.model_config(), estimate="mode")
    logits = jnp.asarray(np.random.default_rng(0).normal(size=(1, 16, 8, 32)) * 3, jnp.float32)
    out = loaded.regress(logits, jnp.asarray(cand, jnp.float32))
    want = estimate_inverse(out["prob"], 1.0 / jnp.asarray(cand, jnp.float32), "mode", 2)
    np.testing.assert_allclose(np.asarray(out["inv_distance"]), np.asarray(want), rtol=1e-6)
    mean = estimate_inverse(out["prob"], 1.0 / jnp.asarray(cand, jnp.float32), "mean")
    assert np.abs(np.asarray(out["inv_distance"]) - np.asarray(mean)).max() > 1e-3
    picked = save_bundle(model, config_file, tmp_path / "pick", estimate="mode", mode_pick=1)
    assert (plain / WEIGHTS_FILE).read_bytes() == (picked / WEIGHTS_FILE).read_bytes()
    c = json.loads((picked / "config.json").read_text())
    assert c["model"].pop("mode_pick") == 1 and c["model"].pop("estimate") == "mode"
    a["model"].pop("mode_pick", None)
    assert a == c
    loaded, mc, cand = load_model(picked)
    assert mc == dataclasses.replace(cfg.model_config(), estimate="mode", mode_pick=1)
    out = loaded.regress(logits, jnp.asarray(cand, jnp.float32))
    want = estimate_inverse(out["prob"], 1.0 / jnp.asarray(cand, jnp.float32), "mode", 2, 1)
    np.testing.assert_allclose(np.asarray(out["inv_distance"]), np.asarray(want), rtol=1e-6)
    # Read at Tulyakov's rule instead (--estimate's mechanism), the same weights give pick 0's,
    # which differ from pick 1's on these logits.
    assert with_estimate(loaded, "mode", 1) is loaded
    tulyakov = with_estimate(loaded, None, 0)
    assert tulyakov.config == dataclasses.replace(mc, mode_pick=0)
    np.testing.assert_allclose(
        np.asarray(tulyakov.regress(logits, jnp.asarray(cand, jnp.float32))["inv_distance"]),
        np.asarray(estimate_inverse(out["prob"], 1.0 / jnp.asarray(cand, jnp.float32), "mode",
                                    2, 0)), rtol=1e-6)
    assert np.abs(np.asarray(tulyakov.regress(logits, jnp.asarray(cand, jnp.float32))
                             ["inv_distance"]) - np.asarray(want)).max() > 1e-3
    with pytest.raises(ValueError, match="pick"):
        save_bundle(model, config_file, tmp_path / "never", mode_pick=-1)
    with pytest.raises(ValueError, match="estimate"):
        write_bundle(tmp_path / "run", tmp_path / "never", estimate="median")
    with pytest.raises(ValueError, match="estimate"):
        save_bundle(model, config_file, tmp_path / "never", estimate="median")
    assert not (tmp_path / "never").exists()


def test_bundle_of_another_network_is_refused(tmp_path):
    cfg, config_file = _run_config(tmp_path)
    other = create_model(dataclasses.replace(cfg.model_config(), unet_base=8))
    out = save_bundle(other, config_file, tmp_path / "bundle")
    with pytest.raises(ValueError, match=WEIGHTS_FILE):
        load_bundle(out)


def test_a_bundle_replaces_only_a_bundle_and_survives_a_kill_mid_swap(tmp_path, monkeypatch):
    """``save_bundle`` refuses, before any work and naming the folder, an output that is not a
    bundle (a dataset-like folder: every file stays), one that holds an input, and the working
    folder; it replaces an existing bundle. A kill after the old bundle was moved aside (and
    before the new one was renamed in) is recovered by the next call: the old bundle comes
    back, the temporaries go."""
    import os

    cfg, config_file = _run_config(tmp_path)
    model = create_model(cfg.model_config(), seed=3)
    data = tmp_path / "dataset"
    data.mkdir()
    for name in ("metadata.json", "manifest.json", "cam0.png"):
        (data / name).write_text(name)
    with pytest.raises(ValueError, match=r"bundle folder .*dataset: exists and is not a bundle "
                                         r"\(it holds cam0.png, manifest.json, metadata.json\)"):
        save_bundle(model, config_file, data)
    assert sorted(p.name for p in data.iterdir()) == ["cam0.png", "manifest.json",
                                                      "metadata.json"]
    with pytest.raises(ValueError, match="holds the input"):
        save_bundle(model, config_file, config_file.parent)
    monkeypatch.chdir(data)
    with pytest.raises(ValueError, match="is the working folder or holds it"):
        save_bundle(model, config_file, tmp_path)
    with pytest.raises(ValueError, match="is the working folder or holds it"):
        save_bundle(model, config_file, ".")
    monkeypatch.chdir(tmp_path)

    out = save_bundle(model, config_file, tmp_path / "bundle", {"v": 1})
    save_bundle(model, config_file, out, {"v": 2})          # a bundle is replaced
    assert json.loads((out / "PROVENANCE.json").read_text()) == {"v": 2}

    real_replace = os.replace

    def killed_after_moving_aside(src, dst):
        real_replace(src, dst)
        if ".old-" in str(dst):
            raise KeyboardInterrupt          # the process dies between the two renames

    monkeypatch.setattr(os, "replace", killed_after_moving_aside)
    with pytest.raises(KeyboardInterrupt):
        save_bundle(model, config_file, out, {"v": 3})
    monkeypatch.setattr(os, "replace", real_replace)
    assert not out.exists() and len(list(tmp_path.glob(".bundle.old-*"))) == 1
    save_bundle(model, config_file, tmp_path / "elsewhere")  # another bundle: no recovery here
    assert not out.exists()
    from gijax.io.replace import recover
    from gijax.train.bundle import BUNDLE

    recover(out, BUNDLE)                     # what the next call on this bundle does first
    assert json.loads((out / "PROVENANCE.json").read_text()) == {"v": 2}
    save_bundle(model, config_file, out, {"v": 4})
    assert json.loads((out / "PROVENANCE.json").read_text()) == {"v": 4}
    assert [p.name for p in tmp_path.glob(".bundle.*") if p.is_dir()] == []


def test_non_finite_weights_are_refused_naming_the_array(tmp_path):
    cfg, config_file = _run_config(tmp_path)
    out = save_bundle(create_model(cfg.model_config(), seed=3), config_file, tmp_path / "b")
    with np.load(out / WEIGHTS_FILE) as f:
        weights = {k: f[k] for k in f.files}
    key = sorted(k for k in weights if k.endswith("kernel"))[0]
    weights[key] = weights[key].copy()
    weights[key].flat[3] = np.nan
    np.savez(out / WEIGHTS_FILE, **weights)
    with pytest.raises(ValueError, match=rf"weights.npz: weights {key} hold 1 non-finite"):
        load_bundle(out)


def test_a_bundle_without_its_weights_is_called_a_damaged_bundle(tmp_path):
    cfg, config_file = _run_config(tmp_path)
    out = save_bundle(create_model(cfg.model_config(), seed=3), config_file, tmp_path / "b")
    (out / WEIGHTS_FILE).unlink()
    with pytest.raises(FileNotFoundError, match=r"bundle .*b lacks its weights.npz"):
        load_model(out)


def test_truncated_weights_name_the_file(tmp_path):
    cfg, config_file = _run_config(tmp_path)
    out = save_bundle(create_model(cfg.model_config()), config_file, tmp_path / "bundle")
    data = (out / WEIGHTS_FILE).read_bytes()
    (out / WEIGHTS_FILE).write_bytes(data[: len(data) // 3])
    with pytest.raises(ValueError, match=WEIGHTS_FILE):
        load_bundle(out)


def test_preset_exists_for_bundled_model():
    assert get_preset("G16VV-cpu").num_candidates == 16


def _leaves(tree):
    import jax

    return jax.tree_util.tree_leaves(tree)


def jax_tree_scale(state, factor):
    import jax

    return jax.tree_util.tree_map(lambda x: x * factor + 0.01, state)


def test_bundled_model_fits_the_network_and_beats_a_constant():
    """The model the demo ships loads into today's network and, on a fresh rendered scene of
    its training rig, beats the best constant inverse distance (the scene's own median) by a
    wide margin: a bundle left behind by an architecture change fails here, not in the demo."""
    import numpy as np

    from gijax.demo import DEFAULT_MODEL
    from gijax.geometry.layouts import builtin_rig
    from gijax.geometry.panorama import Panorama
    from gijax.geometry.rig import scale_rig
    from gijax.predict import predict
    from gijax.render import render_sample

    model, config, cand = load_model(DEFAULT_MODEL)
    rig = scale_rig(builtin_rig("paper-train"), config.image_scale)
    sample = render_sample(rig, 20261129, pano=Panorama.hemisphere(*config.output_hw))
    res = predict(model, rig, sample["images"], sample["masks"], np.asarray(cand))
    d = np.asarray(sample["pano_distance"], np.float64)
    cand = np.asarray(cand, np.float64)
    # Scored as the paper scores: labels inside the candidate range, in 1/m.
    scored = np.isfinite(d) & (d >= cand[0]) & (d <= cand[-1]) & np.asarray(res["valid"])
    assert scored.mean() > 0.3
    inv_gt = 1.0 / d[scored]
    mae = np.mean(np.abs(np.asarray(res["inv_distance"], np.float64)[scored] - inv_gt))
    constant = np.mean(np.abs(np.median(inv_gt) - inv_gt))
    assert mae < 0.5 * constant, (mae, constant)


def test_a_bundle_with_its_figures_is_replaced_whole_and_a_users_file_is_never_taken(tmp_path):
    """A bundle's figures (learning curve, validation figures) are written with it, in the same
    replacement, so a bundle published with figures can be published again; a file of another
    name in the folder (the user's) makes the folder not a bundle; a figure of another name is
    refused before any work."""
    cfg, config_file = _run_config(tmp_path)
    model = create_model(cfg.model_config(), seed=3)
    png = tmp_path / "curve.png"
    png.write_bytes(b"\x89PNG first")
    figures = {"learning_curve.png": png, "validation_paper-test1.png": png}
    out = save_bundle(model, config_file, tmp_path / "bundle", {"v": 1}, figures=figures)
    assert sorted(p.name for p in out.iterdir()) == [
        "PROVENANCE.json", "config.json", "learning_curve.png", "validation_paper-test1.png",
        "weights.npz"]
    png.write_bytes(b"\x89PNG second")
    save_bundle(model, config_file, out, {"v": 2}, figures={"learning_curve.png": png})
    assert (out / "learning_curve.png").read_bytes() == b"\x89PNG second"
    assert not (out / "validation_paper-test1.png").exists()   # the old bundle went whole
    (out / "notes.png").write_text("mine")
    with pytest.raises(ValueError, match=r"exists and is not a bundle \(it holds notes.png\)"):
        save_bundle(model, config_file, out, {"v": 3})
    assert (out / "notes.png").read_text() == "mine"
    with pytest.raises(ValueError, match="bundle figures must be named"):
        save_bundle(model, config_file, tmp_path / "b2", figures={"curve.png": png})
    with pytest.raises(ValueError, match="bundle figures must be named"):
        save_bundle(model, config_file, tmp_path / "b2", figures={"weights.npz": png})
    assert not (tmp_path / "b2").exists()


def _pack_of(model, folder, config_file, step):
    """A resume pack of ``model`` as the trainer writes one (state pytree of params, rest,
    Adam's moments and the step; the run's network configuration and list in its meta)."""
    import optax

    from gijax.store.packs import read_pack, write_pack
    from gijax.train.step import split_model

    _, _, params, rest = split_model(model)
    state = {"params": params, "rest": rest, "opt": optax.adam(1e-3).init(params),
             "step": jnp.asarray(step, jnp.int32)}
    doc = json.loads(config_file.read_text())
    write_pack(folder, state, {"step": step, "model_config": doc["model"],
                               "candidates": doc["candidates"]}, [])
    return read_pack(folder)


def test_a_bundle_averaged_from_packs_holds_the_mean_of_their_variables(tmp_path):
    from gijax.store.bundles import flatten_variables
    from gijax.store.packs import model_variables
    from gijax.train.bundle import average_variables, save_averaged_bundle

    cfg, config_file = _run_config(tmp_path)
    models = [create_model(cfg.model_config(), seed=s) for s in (3, 4)]
    # BatchNorm statistics that differ between the two, as two trainings' would.
    for m, v in zip(models, (0.5, 2.0)):
        nnx.update(m, jax_tree_scale(nnx.state(m, nnx.BatchStat), v))
    packs = [_pack_of(m, tmp_path / f"pack{i}", config_file, 100 * (i + 1))
             for i, m in enumerate(models)]
    # The pack's variables are the model's, keyed as a bundle keys them.
    want = [flatten_variables(nnx.to_pure_dict(nnx.state(m))) for m in models]
    got = model_variables(packs[0])
    assert set(got) == set(want[0]) and len(got) > 20
    for k in got:
        np.testing.assert_array_equal(got[k], want[0][k])
    out = save_averaged_bundle(packs, config_file, tmp_path / "bundle", {"command": "test"})
    loaded, mc, cand = load_model(out)
    assert mc == cfg.model_config()
    np.testing.assert_allclose(np.asarray(cand), np.linspace(0.5, 100.0, 16), rtol=1e-6)
    mean = flatten_variables(nnx.to_pure_dict(nnx.state(loaded)))
    moved = 0
    for k, a in want[0].items():
        b = want[1][k]
        if a.dtype.kind == "f":
            np.testing.assert_allclose(mean[k], (a.astype(np.float64) + b) / 2, rtol=1e-6,
                                       atol=1e-7, err_msg=k)
            moved += int(not np.array_equal(a, b))
    assert moved > 20
    # Another network's pack, or sets of other variables, are refused in one line.
    (tmp_path / "other").mkdir()
    other_cfg, other_config = _run_config(tmp_path / "other", unet_base=8)
    other = _pack_of(create_model(other_cfg.model_config()), tmp_path / "pack-other",
                     other_config, 300)
    with pytest.raises(ValueError, match="pack-other.*network configuration"):
        save_averaged_bundle([packs[0], other], config_file, tmp_path / "bundle2")
    with pytest.raises(ValueError, match=r"^b: variable unet/\S+ is float32 \(8,\); a has "
                                         r"float32 \(4,\)$"):
        average_variables([want[0], model_variables(other)], ["a", "b"])
    # A pack is a model by itself (what --ckpt and --init-from take): the first model's
    # variables, its network and list; a pack that does not say its network is refused in one
    # line naming the file and the field.
    alone, alone_mc, alone_cand = load_model(packs[0].folder)
    assert alone_mc == cfg.model_config()
    np.testing.assert_allclose(np.asarray(alone_cand), np.linspace(0.5, 100.0, 16), rtol=1e-6)
    got = flatten_variables(nnx.to_pure_dict(nnx.state(alone)))
    assert set(got) == set(want[0])
    for k, a in want[0].items():
        np.testing.assert_array_equal(got[k], a, err_msg=k)
    doc_path = tmp_path / "pack-other" / "pack.json"
    doc = json.loads(doc_path.read_text())
    del doc["model_config"]
    doc_path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"pack-other/pack.json: field 'model_config' must be "
                                         r"present"):
        load_model(tmp_path / "pack-other")
    fewer = dict(want[1])
    fewer.pop(sorted(fewer)[0])
    with pytest.raises(ValueError, match=f"^b: holds other network variables than a .*"
                                         f"{sorted(want[0])[0]}"):
        average_variables([want[0], fewer], ["a", "b"])
    with pytest.raises(ValueError, match="at least one"):
        average_variables([])


def test_a_bundle_without_the_matching_skip_starts_a_run_that_adds_it(tmp_path):
    """``init_from`` a bundle of a matching-cost network into a run with ``matching_skip``:
    every shared parameter and BatchNorm statistic is the bundle's, the skip's kernel is the
    run's own zero start; a run that changes anything else (here the U-Net's width) is still
    refused naming the field, and a skip cannot be dropped (a bundle with one into a run
    without it)."""
    from gijax.train.run_folder import initial_variables

    cfg, config_file = _run_config(tmp_path, matching_cost="zncc")
    source = create_model(cfg.model_config(), seed=3)
    nnx.update(source, jax_tree_scale(nnx.state(source, nnx.Param), 1.5))
    bundle = save_bundle(source, config_file, tmp_path / "bundle")

    grown = dataclasses.replace(cfg.model_config(), matching_skip=True)
    fresh = create_model(grown, seed=5)
    fresh.train()
    _, params, rest = nnx.split(fresh, nnx.Param, ...)
    run = TrainConfig(preset="G16VV-cpu", init_from=str(bundle))
    got_params, got_rest = initial_variables(run, grown, params, rest)
    got = (nnx.to_pure_dict(got_params), nnx.to_pure_dict(got_rest))
    skip = got[0].pop("matching_skip")
    assert not np.any(np.asarray(skip["conv"]["kernel"]))
    assert skip["conv"]["kernel"].shape == (3, 3, 3, 1, 1)
    source.train()
    _, *want = nnx.split(source, nnx.Param, ...)
    flat_w, flat_g = (np.concatenate([np.ravel(x) for x in _leaves(t)])
                      for t in ([nnx.to_pure_dict(s) for s in want], got))
    assert flat_w.size > 1000
    np.testing.assert_array_equal(flat_w, flat_g)

    wider = dataclasses.replace(grown, unet_base=8)
    wide = create_model(wider, seed=5)
    _, p, r = nnx.split(wide, nnx.Param, ...)
    with pytest.raises(ValueError, match=r"unet_base \(its 4, this run's 8\)"):
        initial_variables(run, wider, p, r)
    with_skip = save_bundle(create_model(grown, seed=1), config_file, tmp_path / "skip")
    # The run config copied in names no skip; the bundle's config must, for this direction.
    doc = json.loads((with_skip / "config.json").read_text())
    doc["model"]["matching_skip"] = True
    (with_skip / "config.json").write_text(json.dumps(doc))
    _, p, r = nnx.split(create_model(cfg.model_config(), seed=5), nnx.Param, ...)
    with pytest.raises(ValueError, match=r"matching_skip \(its True, this run's False\)"):
        initial_variables(TrainConfig(preset="G16VV-cpu", init_from=str(with_skip)),
                          cfg.model_config(), p, r)
