"""Training end to end: a tiny network overfits, the CLI trains and evaluates, bad input fails."""

import json
import os
import shlex
from pathlib import Path

import jax
import numpy as np
import pytest

from test_events import event_file_records
from test_train_faults import CACHE, CHILD

# The helpers of the child script (tiny network overrides, in-memory samples, rig) run here too.
_NS: dict = {}
exec(compile(CHILD.split('if __name__ == "__main__":')[0], "train_child", "exec"), _NS)
TINY, CANDIDATES, tiny_arrays, tiny_rig = (_NS[k] for k in ("TINY", "CANDIDATES", "tiny_arrays",
                                                             "tiny_rig"))


@pytest.fixture(scope="module", autouse=True)
def compile_cache():
    """Share compiled programs with the subprocess tests (same cache folder)."""
    from conftest import persistent_compile_cache

    yield from persistent_compile_cache(CACHE)


def _config(**kw):
    from gijax.train.config import TrainConfig

    base = dict(preset="E8-cpu", model_overrides=TINY, lr=3e-3, batch_size=2, steps=60,
                ckpt_every=0, val_every=0, keep_best=False, candidates=CANDIDATES)
    base.update(kw)
    return TrainConfig(**base)


@pytest.mark.usefixtures("quick_compiles_here")
def test_tiny_network_overfits_two_samples(tmp_path):
    """Smooth-L1 E8 network (tiny sizes), 2 samples, 60 Adam steps at lr 3e-3: the MAE on the
    training samples drops from about 0.21 1/m (untrained) below 0.04 1/m. A plain step (no
    gradient accumulation), compiled without XLA's optimisation passes as the other training
    tests here: they only round differently, which the margins of the drop do not feel, and
    they dominate the compile time of the step."""
    from gijax.train.sources import array_stream_factory
    from gijax.train.trainer import Trainer

    arr = tiny_arrays(2)
    t = Trainer(_config(), tmp_path / "run", tiny_rig(), array_stream_factory(arr, 2, 0),
                lambda: [arr], progress=False)
    before = t.validate(0)["mae"]
    t.fit()
    after = t.validate(60)
    t.close()
    assert before > 0.15, before
    assert after["mae"] < 0.04 and after["mae"] < 0.2 * before, (before, after)
    losses = [r["loss"] for r in t.history if "loss" in r]
    assert len(losses) == 60 and np.mean(losses[-5:]) < 0.2 * np.mean(losses[:5])
    assert sorted(os.listdir(tmp_path / "run" / "samples"))[0].endswith("sample0.png")


def _write_tiny_dataset(root: Path, n: int, seed: int):
    """Synthetic samples at 64 x 64 per camera and a 16 x 64 panorama (no rendering needed)."""
    from gijax.data import write_dataset
    from gijax.geometry.panorama import Panorama
    from gijax.geometry.rig import scale_rig

    rig = scale_rig(tiny_rig(), 1 / 16)
    rng = np.random.default_rng(seed)
    arr = tiny_arrays(n, seed)

    def sample(i):
        h, w = rig.cameras[0].height, rig.cameras[0].width
        return {"images": rng.integers(0, 256, (3, h, w, 3), dtype=np.uint8),
                "distances": np.full((3, h, w), 2.0, np.float32),
                "masks": np.ones((3, h, w), np.uint8),
                "pano_distance": arr["distance"][i].astype(np.float32)}

    write_dataset(root, sample, rig, Panorama.hemisphere(16, 64), num_samples=n)
    return rig


@pytest.mark.usefixtures("quick_compiles_here")
def test_cli_train_eval_and_bad_input(tmp_path, capsys):
    from gijax.cli import main

    _write_tiny_dataset(tmp_path / "train", 4, 0)
    _write_tiny_dataset(tmp_path / "val", 2, 1)
    overrides = sum([["--override", f"{k}={json.dumps(v)}"] for k, v in TINY.items()], [])
    cand = tmp_path / "cand.json"
    cand.write_text(json.dumps(CANDIDATES))
    run = tmp_path / "run"
    argv = ["train", "--preset", "E8-cpu", "--data", str(tmp_path / "train"), "--val",
            str(tmp_path / "val"), "--out", str(run), "--steps", "4", "--batch", "2",
            "--val-every", "2", "--ckpt-every", "2", "--candidates", str(cand), "--lr", "1e-3",
            "--workers", "0", "--no-progress", *overrides]
    assert main(argv) == 0
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["train"]["preset"] == "E8-cpu" and cfg["candidates"] == CANDIDATES
    recs = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in recs if "loss" in r] == [1, 2, 3, 4]
    # The run says what started it: the command line as given, the code and package versions.
    started = recs[0]
    assert started["event"] == "started" and started["step"] == 0
    assert started["command"] == shlex.join(["gijax", *argv])
    assert started["versions"]["jax"] == jax.__version__ and set(started["git"]) == {"commit",
                                                                                      "dirty"}
    vals = [r for r in recs if r.get("split") == "val"]
    assert [v["step"] for v in vals] == [2, 4]
    assert sorted(os.listdir(run / "checkpoints")) == ["2", "4"]
    best_step = int(os.listdir(run / "best")[0])
    best_mae = min(v["mae"] for v in vals)
    assert [v["mae"] for v in vals if v["step"] == best_step] == [best_mae]
    events = list((run / "tb").glob("events.out.tfevents.*"))
    recorded = [e for path in events for e in event_file_records(path)]
    assert recorded[0].file_version == "brain.Event:2"
    tags = {(v.tag, e.step) for e in recorded for v in e.summary.value}
    assert {("val/mae", v["step"]) for v in vals} <= tags
    images = [v.image for e in recorded for v in e.summary.value if v.HasField("image")]
    assert images and all(i.encoded_image_string.startswith(b"\x89PNG") for i in images)
    assert len(list((run / "samples").glob("*.png"))) == 4

    out_json = tmp_path / "eval.json"
    capsys.readouterr()
    assert main(["eval", "--ckpt", str(run), "--data", str(tmp_path / "val"), "--json",
                 str(out_json)]) == 0
    printed = capsys.readouterr().out
    assert "MAE" in printed and "SSIM" in printed
    res = json.loads(out_json.read_text())
    assert res["metric_set"] == "paper" and "torchmetrics" in res["metric_definitions"]
    assert res["samples"] == 2 and res["time_ms_per_sample"] > 0 and res["host_peak_mb"] > 0
    # Each scene's own metrics: the paper's MAE is their mean over samples.
    assert len(res["per_scene"]) == 2
    assert res["mae"] == pytest.approx(np.mean([s["mae"] for s in res["per_scene"]]), rel=1e-6)
    assert res["per_scene"][0]["mae"] != res["per_scene"][1]["mae"]
    # the best checkpoint, evaluated again with the training's (gijax) definitions, reproduces
    # the validation MAE logged in training
    assert main(["eval", "--ckpt", str(run), "--data", str(tmp_path / "val"), "--metrics",
                 "gijax", "--json", str(out_json)]) == 0
    res = json.loads(out_json.read_text())
    assert res["metric_set"] == "gijax" and res["estimate"] == "mean"
    assert abs(res["mae"] - best_mae) < 1e-5, (res["mae"], best_mae)
    # The same weights read by their sub-pixel mode: another estimate, recorded as such.
    assert main(["eval", "--ckpt", str(run), "--data", str(tmp_path / "val"), "--metrics",
                 "gijax", "--estimate", "mode", "--json", str(out_json)]) == 0
    mode = json.loads(out_json.read_text())
    assert mode["estimate"] == "mode" and mode["mae"] != pytest.approx(res["mae"], rel=1e-6)

    # --- bad input: each a clear error (exit code 1 and a message naming the problem)
    def fails(args, *words):
        capsys.readouterr()
        assert main(args) == 1
        err = capsys.readouterr().err
        for w in words:
            assert w in err, (w, err)

    fails(["eval", "--method", "rtss", "--data", str(tmp_path / "val"), "--estimate", "mode"],
          "--estimate", "--method rtss")
    base = [a if a != "E8-cpu" else "G8-cpu" for a in argv]
    fails(base, "preset", "E8-cpu", "G8-cpu")                    # resume with another preset
    fails(argv + ["--override", "num_candidates=16"], "8 candidates", "16")  # another candidate count
    fails(argv + ["--override", "unet_base=4"], "another network configuration")
    # Another 3-D conv lowering computes the same weights: the finished run resumes (and stops).
    assert main(argv + ["--override", 'conv3d="native"']) == 0
    resumed = json.loads((run / "metrics.jsonl").read_text().splitlines()[-1])
    assert resumed["event"] == "resumed" and resumed["step"] == 4
    assert resumed["command"].endswith("""--override 'conv3d="native"'""")
    fails([("--out" if a == "--out" else (str(tmp_path / "run2") if a == str(run) else a))
           for a in argv[:argv.index("--batch") + 1]] + ["8"] + argv[argv.index("--batch") + 2:],
          "batch size 8", "larger")                               # batch larger than the data
    from gijax.data import DatasetWriter
    from gijax.geometry.panorama import Panorama
    from gijax.geometry.rig import scale_rig

    DatasetWriter(tmp_path / "empty", scale_rig(tiny_rig(), 1 / 16), Panorama.hemisphere(16, 64))
    fails(["train", "--preset", "E8-cpu", "--data", str(tmp_path / "empty"), "--out",
           str(tmp_path / "run3")], "no samples")
    fails(["eval", "--ckpt", str(run), "--data", str(tmp_path / "val"), "--candidates", "x.json"],
          "x.json")
    fails(["eval", "--ckpt", str(run), "--data", str(tmp_path / "val"), "--rig", "paper-test3"],
          "--rig paper-test3 has 4 camera(s)", "holds images of 3")


@pytest.mark.usefixtures("quick_compiles_here")
def test_all_checkpoints_corrupt_is_a_clear_error(tmp_path):
    import jax.numpy as jnp

    from gijax.store.checkpoints import CheckpointStore

    store = CheckpointStore(tmp_path, keep=2, best_metric=None)
    state = {"w": jnp.arange(4.0)}
    store.save(1, state, {"step": 1})
    for f in (tmp_path / "checkpoints" / "1").rglob("*"):
        if f.is_file():
            f.write_bytes(b"garbage")
    abstract = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), state)
    with pytest.warns(RuntimeWarning, match="unreadable"):
        with pytest.raises(ValueError, match="no readable checkpoint"):
            store.restore_latest(abstract)


def test_grad_accum_and_bf16_step_agree_with_plain_step():
    """One step from the same state and batch. With 2 accumulated micro-batches the reported
    loss is the mean of the micro-batches' losses, each the training-mode loss of that sample
    alone (what a plain step on it reports; BatchNorm normalises each micro-batch by its own
    statistics in training mode, so it is not the loss of the whole batch); in bfloat16 it
    agrees to bfloat16 accuracy. The per-sample losses come from the forward pass alone, a
    smaller program than a train step."""
    import jax.numpy as jnp
    from flax import nnx

    from gijax.model import create_model, model_grids, model_rig
    from gijax.train import step as S
    from gijax.train.losses import model_loss

    cfg = _config()
    mc = cfg.model_config()
    tdef, _, params, rest = S.split_model(create_model(mc, 0))
    tx = S.make_optimizer(cfg)
    mesh = S.make_mesh(jax.devices()[:1])
    arr = tiny_arrays(2)
    rig = model_rig(_NS["tiny_rig"]())
    cand = jnp.asarray(CANDIDATES, jnp.float32)

    @jax.jit
    def sample_loss(params, rest, batch):
        model = nnx.merge(tdef, params, jax.tree.map(lambda x: x, rest))
        out = model(batch["surrogates"].astype(jnp.float32), batch["masks"],
                    model_grids(mc, rig, cand))
        return model_loss(mc.loss, out, batch["distance"], batch["valid"], cand)

    per_sample = np.mean([float(sample_loss(params, rest, {k: v[i:i + 1] for k, v in
                                                           arr.items()})) for i in range(2)])
    out = {}
    for name, bf16 in (("accum", False), ("accum_bf16", True)):
        state = S.place_state(S.init_state(params, rest, tx), mesh)
        step = jax.jit(S.build_train_step(tdef, tx, mc.loss, 2, bf16))
        new, m = step(state, S.place_batch(arr, mesh), rig, cand)
        out[name] = (float(m["loss"]), new)
    np.testing.assert_allclose(out["accum"][0], per_sample, rtol=1e-5)
    l0, l1 = out["accum"][0], out["accum_bf16"][0]
    assert np.isfinite(l1) and abs(l1 - l0) < 0.05 * abs(l0), (l0, l1)
    p0 = jax.tree.leaves(out["accum"][1]["params"])
    p1 = jax.tree.leaves(out["accum_bf16"][1]["params"])
    assert all(a.dtype == b.dtype == jnp.float32 for a, b in zip(p0, p1))   # params stay f32


@pytest.mark.usefixtures("quick_compiles_here")
def test_learned_candidate_list_trains_is_saved_and_is_what_the_run_predicts_with(tmp_path):
    """--learn-candidates: the list moves with the network, keeps its ends, is logged at each
    validation, written to candidates.json, stored in the checkpoints and returned (and bundled)
    by the store; resuming under the other setting is refused."""
    from gijax.store.runs import load_for_inference
    from gijax.train.bundle import write_bundle
    from gijax.train.sources import array_stream_factory
    from gijax.train.trainer import Trainer

    arr = tiny_arrays(2)
    run = tmp_path / "run"
    cfg = _config(steps=6, ckpt_every=3, val_every=3, keep_best=True, learn_candidates=True,
                  candidates_lr=0.05)
    t = Trainer(cfg, run, tiny_rig(), array_stream_factory(arr, 2, 0), lambda: [arr],
                progress=False)
    t.fit()
    t.close()
    learned = json.loads((run / "candidates.json").read_text())
    cand = np.asarray(learned["candidates"])
    assert learned["step"] == 6 and np.allclose(learned["initial"], CANDIDATES)
    assert cand[0] == pytest.approx(CANDIDATES[0]) and cand[-1] == pytest.approx(CANDIDATES[-1])
    assert np.all(np.diff(cand) > 0)
    assert np.abs(cand - np.asarray(CANDIDATES)).max() > 1e-4       # it did move
    vals = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()
            if '"split": "val"' in line]
    assert [v["step"] for v in vals] == [3, 6] and len(vals[-1]["candidates"]) == len(cand)
    _, _, got = load_for_inference(run, which="latest")
    np.testing.assert_allclose(got, cand, rtol=1e-6)
    bundle = write_bundle(run, tmp_path / "bundle", which="latest")
    np.testing.assert_allclose(json.loads((bundle / "config.json").read_text())["candidates"],
                               cand, rtol=1e-6)
    with pytest.raises(ValueError, match="learned candidate list"):
        Trainer(_config(steps=8), run, tiny_rig(), array_stream_factory(arr, 2, 0), None,
                progress=False)


def _source(batch: dict, arrays: list) -> int:
    """Which of ``arrays`` every sample of ``batch`` comes from (by its surrogates)."""
    imgs = np.asarray(batch["surrogates"])
    owners = {i for x in imgs for i, a in enumerate(arrays)
              if any(np.array_equal(x, y) for y in a["surrogates"])}
    assert len(owners) == 1, owners
    return owners.pop()


def test_mixed_stream_draws_in_proportion_and_resumes_exactly():
    """Two datasets of 4 and 8 samples: each batch comes whole from the dataset it names, about
    a third of the batches from the smaller one, and a stream rebuilt from its saved state
    continues with exactly the batches an uninterrupted stream gives."""
    from gijax.train.sources import RIG_KEY, array_stream_factory, mixed_stream_factory

    a, b = tiny_arrays(4, 0), tiny_arrays(8, 1)
    make = mixed_stream_factory([array_stream_factory(a, 2, 0), array_stream_factory(b, 2, 0)],
                                [4, 8], seed=3)
    s = make(None)
    full = [next(s) for _ in range(60)]
    idx = [x[RIG_KEY] for x in full]
    assert [_source(x, [a, b]) for x in full] == idx
    assert 0.2 < idx.count(0) / len(idx) < 0.47, idx.count(0)
    part = make(None)
    for _ in range(17):
        next(part)
    resumed = make(json.loads(json.dumps(part.state())))
    for x, y in zip(full[17:], (next(resumed) for _ in range(43))):
        assert x[RIG_KEY] == y[RIG_KEY]
        np.testing.assert_array_equal(x["surrogates"], y["surrogates"])
    with pytest.raises(ValueError, match="saved for 1 training datasets; this run has 2"):
        make({"step": 0, "streams": [None]})
    with pytest.raises(ValueError, match="positive weight"):
        mixed_stream_factory([array_stream_factory(a, 2, 0)], [0], 0)(None)


@pytest.mark.usefixtures("quick_compiles_here")
def test_each_batch_of_mixed_datasets_is_trained_with_its_own_rig(tmp_path):
    """A run over two datasets with different rigs passes each batch's own rig to the step."""
    from gijax.train.sources import array_stream_factory, mixed_stream_factory
    from gijax.train.trainer import Trainer

    rig0 = tiny_rig()
    rig1 = rig0.replace(translations=rig0.translations * 2.0)
    a, b = tiny_arrays(2, 0), tiny_arrays(4, 1)
    make = mixed_stream_factory([array_stream_factory(a, 2, 0), array_stream_factory(b, 2, 0)],
                                [2, 4], seed=0)
    t = Trainer(_config(steps=6), tmp_path / "run", [rig0, rig1], make, None, progress=False)
    inner, seen = t._step, []

    def spy(state, batch, rig, cand):
        seen.append((_source({"surrogates": np.asarray(batch["surrogates"])}, [a, b]),
                     np.asarray(rig.translations)))
        return inner(state, batch, rig, cand)

    t._step = spy
    t.fit()
    t.close()
    assert {s for s, _ in seen} == {0, 1}
    for s, trans in seen:
        np.testing.assert_allclose(trans, np.asarray((rig0, rig1)[s].translations))


def test_mixed_training_datasets_must_share_the_label_panorama(tmp_path):
    """Folders whose labels differ in size are refused naming both; --rig with several
    training folders is refused."""
    from gijax.data import write_dataset
    from gijax.geometry.panorama import Panorama
    from gijax.train.entry import train

    rig = _write_tiny_dataset(tmp_path / "a", 2, 0)
    h, w = rig.cameras[0].height, rig.cameras[0].width

    def sample(i):
        return {"images": np.zeros((3, h, w, 3), np.uint8),
                "distances": np.full((3, h, w), 2.0, np.float32),
                "masks": np.ones((3, h, w), np.uint8),
                "pano_distance": np.full((32, 128), 2.0, np.float32)}

    write_dataset(tmp_path / "b", sample, rig, Panorama.hemisphere(32, 128), num_samples=2)
    with pytest.raises(ValueError, match=r"different label panoramas \(16 x 64 hemisphere vs "
                                         r"32 x 128 hemisphere\)") as err:
        train(_config(steps=1), [tmp_path / "a", tmp_path / "b"], tmp_path / "run",
              progress=False)
    assert str(tmp_path / "b") in str(err.value) and not (tmp_path / "run").exists()
    with pytest.raises(ValueError, match="applies to one training dataset"):
        train(_config(steps=1), [tmp_path / "a", tmp_path / "a"], tmp_path / "run",
              rig="paper-train", progress=False)


@pytest.mark.usefixtures("quick_compiles_here")
def test_calibration_error_turns_each_steps_rig_within_its_bound(tmp_path):
    """--calibration-error 0.5: every step's rig has each camera turned by a rotation of at
    most 0.5 degrees (measured from the rotation matrices), a new one each step, the same one
    for the same step in another run; positions and the labels' rig are untouched."""
    from gijax.train.sources import array_stream_factory
    from gijax.train.trainer import Trainer

    rig = tiny_rig()
    arr = tiny_arrays(2)
    cfg = _config(steps=4, calibration_error_deg=0.5)
    t = Trainer(cfg, tmp_path / "run", rig, array_stream_factory(arr, 2, 0), None, progress=False)
    inner, seen = t._step, []

    def spy(state, batch, r, cand):
        seen.append(r)
        return inner(state, batch, r, cand)

    t._step = spy
    t.fit()
    t.close()
    true_r = np.asarray(rig.rotations, np.float64)
    angles = []
    for r in seen:
        got = np.asarray(r.rotations, np.float64)
        cos = (np.einsum("nij,nij->n", true_r, got) - 1.0) / 2.0
        angles.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
        np.testing.assert_allclose(r.translations, rig.translations)
    angles = np.asarray(angles)
    assert np.all(angles <= 0.5 + 1e-3) and np.all(angles > 1e-3), angles
    assert len({round(float(a), 6) for a in angles[:, 0]}) == 4          # new each step
    again = Trainer(cfg, tmp_path / "run2", rig, array_stream_factory(arr, 2, 0), None,
                    progress=False)
    np.testing.assert_allclose(again.calibrated_rig(t.rig, 2).rotations, seen[2].rotations,
                               atol=1e-7)
    again.close()
    with pytest.raises(ValueError, match="calibration_error_deg"):
        _config(calibration_error_deg=-1.0)


@pytest.mark.usefixtures("quick_compiles_here")
def test_non_finite_loss_stops_the_run_before_it_is_saved(tmp_path):
    """A batch that makes the loss NaN at step 3 stops training with an error naming step 3,
    although losses are read one step late; the checkpoints end at step 2."""
    from gijax.train.sources import array_stream_factory
    from gijax.train.trainer import Trainer

    arr = tiny_arrays(2)
    good = array_stream_factory(arr, 2, 0)

    class Poisoned:
        def __init__(self, state=None):
            self.inner, self.n = good(state), 0

        def __next__(self):
            self.n += 1
            batch = dict(next(self.inner))
            if self.n == 3:
                batch["surrogates"] = np.full_like(batch["surrogates"], np.nan)
            return batch

        def state(self):
            return self.inner.state()

    run = tmp_path / "run"
    t = Trainer(_config(steps=6, ckpt_every=1, keep=10), run, tiny_rig(), Poisoned, None,
                progress=False)
    with pytest.raises(FloatingPointError, match="became nan at step 3"):
        t.fit()
    t.close()
    assert sorted(int(p.name) for p in (run / "checkpoints").iterdir()) == [1, 2]
    logged = [json.loads(line)["step"] for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert logged == [1, 2]


@pytest.mark.usefixtures("quick_compiles_here")
def test_a_run_started_from_a_trained_model_takes_its_weights_with_a_fresh_optimiser(tmp_path):
    """``init_from`` (fine-tuning): run B, seeded differently, starts from run A's last
    checkpoint: the same parameters and BatchNorm statistics, hence A's validation MAE, with
    Adam's moments and step count at zero. A network of other sizes is refused naming the
    field, and leaves no run folder; once B holds a checkpoint it resumes from it without
    reading its source (here removed)."""
    import shutil

    from gijax.train.sources import array_stream_factory
    from gijax.train.trainer import Trainer

    arr = tiny_arrays(2)
    stream = array_stream_factory(arr, 2, 0)
    a = Trainer(_config(steps=3, ckpt_every=3), tmp_path / "a", tiny_rig(), stream,
                lambda: [arr], progress=False)
    a.fit()
    a_mae = a.validate(3)["mae"]
    a_params, a_rest = a.local_variables()
    a.close()

    b_cfg = _config(steps=2, ckpt_every=2, seed=7, init_from=str(tmp_path / "a"))
    b = Trainer(b_cfg, tmp_path / "b", tiny_rig(), stream, lambda: [arr], progress=False)
    b_params, b_rest = b.local_variables()
    for x, y in zip(jax.tree.leaves((a_params, a_rest)), jax.tree.leaves((b_params, b_rest))):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert b.validate(0)["mae"] == pytest.approx(a_mae, rel=1e-6)
    assert b.start_step == 0 and int(b.state["step"].addressable_data(0)) == 0
    moments = [np.asarray(x.addressable_data(0)) for x in jax.tree.leaves(b.state["opt"])]
    assert moments and all(not np.any(m) for m in moments)
    b.fit()
    b.close()

    # The cost volume at the output's size (output_stride 1), the full sphere, another input
    # scale, another loss and another estimate resize no weight: accepted.
    fine = dict(TINY, cost_hw=list(TINY["output_hw"]), output_stride=1, panorama="sphere",
                image_scale=0.5 * TINY.get("image_scale", 1.0), loss="smooth_l1",
                estimate="mode", mode_window=1)
    f = Trainer(_config(model_overrides=fine, steps=1, init_from=str(tmp_path / "a")),
                tmp_path / "f", tiny_rig(), stream, None, progress=False)
    for x, y in zip(jax.tree.leaves(a_params), jax.tree.leaves(f.local_variables()[0])):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    f.close()
    wider = dict(TINY, unet_base=2 * TINY["unet_base"])
    with pytest.raises(ValueError, match=r"unet_base \(its 8, this run's 16\)"):
        Trainer(_config(model_overrides=wider, init_from=str(tmp_path / "a")), tmp_path / "c",
                tiny_rig(), stream, None, progress=False)
    assert not (tmp_path / "c").exists()

    shutil.rmtree(tmp_path / "a")
    b2 = Trainer(b_cfg, tmp_path / "b", tiny_rig(), stream, None, progress=False)
    assert b2.start_step == 2
    b2.close()


@pytest.mark.usefixtures("quick_compiles_here")
def test_a_run_whose_folder_is_lost_resumes_from_its_pack_with_the_same_losses(tmp_path):
    """A run trained 2 of 4 steps with ``pack`` loses its whole run folder (another machine):
    a new run folder with the same pack starts at step 2 and logs steps 3-4 with the losses of
    an uninterrupted 4-step run, bit for bit (weights, BatchNorm statistics, Adam's moments
    and the data position all came back); the log of steps 1-2 is restored from the pack. A
    pack whose state file was altered, or one of another network, is refused in one line."""
    import shutil

    from gijax.store.packs import read_pack
    from gijax.train.sources import array_stream_factory
    from gijax.train.trainer import Trainer

    arr = tiny_arrays(4)
    stream = array_stream_factory(arr, 2, 0)
    whole = Trainer(_config(steps=4, ckpt_every=2), tmp_path / "whole", tiny_rig(), stream, None,
                    progress=False)
    whole.fit()
    final_params = [np.asarray(x) for x in jax.tree_util.tree_leaves(whole.local_variables()[0])]
    whole.close()
    expected = {r["step"]: r["loss"] for r in whole.history if "loss" in r}

    pack = tmp_path / "pack"
    cfg = _config(steps=4, ckpt_every=2, pack=str(pack))
    first = Trainer(cfg, tmp_path / "run", tiny_rig(), stream, None, progress=False)
    first.fit(steps=2)
    first.close()
    assert read_pack(pack).step == 2 and len(list(pack.glob("state-*.npz"))) == 1
    shutil.rmtree(tmp_path / "run")

    second = Trainer(cfg, tmp_path / "run2", tiny_rig(), stream, None, progress=False)
    assert second.start_step == 2
    second.fit()
    second.close()
    got = {r["step"]: r["loss"] for r in second.history if "loss" in r}
    assert got == {3: expected[3], 4: expected[4]}
    logged = [json.loads(line) for line in (tmp_path / "run2" / "metrics.jsonl").read_text()
              .splitlines()]
    assert [r["step"] for r in logged if "loss" in r] == [1, 2, 3, 4]
    assert [r["loss"] for r in logged if "loss" in r] == [expected[s] for s in (1, 2, 3, 4)]
    assert read_pack(pack).step == 4 and len(list(pack.glob("state-*.npz"))) == 1

    # A finished pack restored into an empty folder trains no step, and the folder still
    # holds its weights: the same parameters as the uninterrupted run's, ready to predict.
    from flax import nnx

    from gijax.store.runs import load_for_inference

    done = Trainer(cfg, tmp_path / "run4", tiny_rig(), stream, None, progress=False)
    done.fit()
    done.close()
    assert not [r for r in done.history if "loss" in r and r["step"] > 4]
    model, _, _ = load_for_inference(tmp_path / "run4", "latest")
    got_params = jax.tree_util.tree_leaves(nnx.state(model, nnx.Param))
    assert len(got_params) == len(final_params)
    for a, b in zip(got_params, final_params):
        np.testing.assert_array_equal(np.asarray(a), b)
    # The pack alone is a model too (what --ckpt and --init-from take on a machine without the
    # run folder): every variable, BatchNorm statistics included, as the run's checkpoint.
    from gijax.store import load_model
    from gijax.store.bundles import flatten_variables

    packed, packed_config, packed_cand = load_model(pack)
    run_vars = flatten_variables(nnx.to_pure_dict(nnx.state(model)))
    pack_vars = flatten_variables(nnx.to_pure_dict(nnx.state(packed)))
    assert sorted(pack_vars) == sorted(run_vars) and any("mean" in k for k in run_vars)
    for key, value in run_vars.items():
        np.testing.assert_array_equal(pack_vars[key], value, err_msg=key)
    assert packed_config == cfg.model_config()
    norms = [m for _, m in nnx.iter_modules(packed) if isinstance(m, nnx.BatchNorm)]
    assert norms and all(m.use_running_average for m in norms)      # in eval mode
    np.testing.assert_allclose(packed_cand, read_pack(pack).meta["candidates"])

    # A damaged state file: refused naming it, before any run folder is made.
    state_file = next(pack.glob("state-*.npz"))
    data = bytearray(state_file.read_bytes())
    data[len(data) // 2] ^= 0xFF
    state_file.write_bytes(bytes(data))
    with pytest.raises(ValueError, match=rf"{state_file.name}: its SHA-256 does not match"):
        Trainer(cfg, tmp_path / "run3", tiny_rig(), stream, None, progress=False)
    assert not (tmp_path / "run3").exists()

    # A pack of another network is not loaded into this one.
    other = tmp_path / "other-pack"
    source = Trainer(_config(steps=2, ckpt_every=2, pack=str(other)), tmp_path / "o",
                     tiny_rig(), stream, None, progress=False)
    source.fit()
    source.close()
    wider = dict(TINY, unet_base=2 * TINY["unet_base"])
    with pytest.raises(ValueError, match=r"resume pack .*other-pack: its network configuration "
                                         r"differs from this run's in unet_base"):
        Trainer(_config(model_overrides=wider, steps=4, ckpt_every=2, pack=str(other)),
                tmp_path / "w", tiny_rig(), stream, None, progress=False)
    # A pack written before a configuration field existed (here `refine`) describes the same
    # network as that field's default: it resumes.
    doc = json.loads((other / "pack.json").read_text())
    del doc["model_config"]["refine"]
    (other / "pack.json").write_text(json.dumps(doc))
    older = Trainer(_config(steps=4, ckpt_every=2, pack=str(other)), tmp_path / "old",
                    tiny_rig(), stream, None, progress=False)
    assert older.start_step == 2
    older.close()


def test_a_folder_that_is_not_a_run_folder_is_never_trained_into(tmp_path):
    """``--out`` naming a dataset (or any folder with files and no ``config.json``) is refused
    in one line before anything is written; its files stay as they were."""
    from gijax.train.sources import array_stream_factory
    from gijax.train.trainer import Trainer

    folder = tmp_path / "dataset"
    folder.mkdir()
    (folder / "manifest.json").write_text("{}")
    arr = tiny_arrays(2)
    with pytest.raises(ValueError, match=r"dataset: exists and is not a gijax run folder \(it "
                                         r"holds manifest.json and no config.json\)"):
        Trainer(_config(steps=1), folder, tiny_rig(), array_stream_factory(arr, 2, 0), None,
                progress=False)
    assert sorted(p.name for p in folder.iterdir()) == ["manifest.json"]


def _mount_tmpfs(path, size: str) -> bool:
    import shutil
    import subprocess

    if shutil.which("mount") is None:
        return False
    path.mkdir(parents=True, exist_ok=True)
    return subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True).returncode == 0


@pytest.mark.usefixtures("quick_compiles_here")
def test_a_full_disk_stops_training_in_one_line_and_the_same_command_continues(tmp_path, capfd):
    """A real full disk (a 300 KB tmpfs: the config and logs fit, the first checkpoint does
    not): one line on stderr, not orbax's per-array tracebacks; the partial checkpoint removed;
    with space freed, the same command completes the run."""
    import subprocess

    from gijax.cli import main

    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, "300k"):
        pytest.skip("needs to mount a small tmpfs (root on Linux)")
    try:
        _write_tiny_dataset(tmp_path / "train", 4, 0)
        overrides = sum([["--override", f"{k}={json.dumps(v)}"] for k, v in TINY.items()], [])
        cand = tmp_path / "cand.json"
        cand.write_text(json.dumps(CANDIDATES))
        argv = ["train", "--preset", "E8-cpu", "--data", str(tmp_path / "train"), "--out",
                str(disk / "run"), "--steps", "4", "--batch", "2", "--ckpt-every", "2",
                "--candidates", str(cand), "--workers", "0", "--no-progress", *overrides]
        capfd.readouterr()
        assert main(argv) == 1
        err = [line for line in capfd.readouterr().err.splitlines() if line.strip()]
        assert len(err) == 1, err
        assert err[0].startswith("gijax train: error: disk full while writing the checkpoint "
                                 "of step 2 into ") and "the same command to continue" in err[0]
        assert not list((disk / "run" / "checkpoints").glob("*tmp*"))
        subprocess.run(["mount", "-o", "remount,size=20m", str(disk)], check=True)
        assert main(argv) == 0
        assert sorted(p.name for p in (disk / "run" / "checkpoints").iterdir()) == ["2", "4"]
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)


def test_compiled_ahead_compiles_each_signature_once_and_trims_the_heap(monkeypatch):
    import jax.numpy as jnp

    from gijax.train import step as S

    trims, lowered = [], []
    monkeypatch.setattr(S, "release_freed_memory", lambda: trims.append(1) or True)
    jitted = jax.jit(lambda x, scale: x * scale + 1.0)

    class Counting:
        def __call__(self, *args):
            return jitted(*args)

        def lower(self, *args):
            lowered.append([np.shape(a) for a in args])
            return jitted.lower(*args)

    f = S.CompiledAhead(Counting())
    np.testing.assert_array_equal(np.asarray(f(jnp.arange(3.0), 2.0)), [1.0, 3.0, 5.0])
    np.testing.assert_array_equal(np.asarray(f(jnp.arange(3.0), 3.0)), [1.0, 4.0, 7.0])
    assert len(lowered) == len(trims) == 1          # same shapes and types: compiled once
    np.testing.assert_array_equal(np.asarray(f(jnp.arange(4.0), 2.0)), [1.0, 3.0, 5.0, 7.0])
    np.testing.assert_array_equal(np.asarray(f(jnp.arange(3, dtype=jnp.int32), 2)), [1, 3, 5])
    assert lowered == [[(3,), ()], [(4,), ()], [(3,), ()]] and len(trims) == 3
