"""Label-free adaptation of a trained network to a rig (``gijax adapt``): the loss terms against
independent references, the objective never reading labels, and a short adaptation run that
resumes exactly and writes a bundle every ``--ckpt`` loads."""

import dataclasses
import json

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gijax.geometry.layouts import builtin_rig
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import scale_rig
from gijax.model import model_rig
from gijax.nn.presets import ModelConfig
from gijax.sweep.surrogate import surrogate_images
from gijax.train.unlabeled import (LabelFree, edge_aware_smoothness, label_free_terms,
                                   normalize_gain, photometric_loss, teacher_confidence,
                                   teacher_loss)

pytestmark = pytest.mark.usefixtures("quick_compiles")

# The tiny network of tests/test_model.py (TINY_VAR) on the paper's rig at 1/16 (64 px).
TINY = ModelConfig(
    name="tiny-variance", num_candidates=8, candidates="gi", loss="volume", features="spherical",
    cost_volume="variance", feature_channels=4, feature_blocks=(1, 1), unet_in=4, unet_base=4,
    surrogate_hw=(32, 128), cost_hw=(8, 32), output_hw=(16, 64), image_scale=1 / 16)
PANO = Panorama.hemisphere(*TINY.output_hw)
# The loss terms are checked on the rig at 1/8 (128 px) and 64 x 256 surrogates: at 64 px the
# rendered texture aliases and every distance looks alike.
SCALE = 1 / 8
SPANO = Panorama.hemisphere(64, 256)
TRUE_DISTANCE = 2.0


@pytest.fixture(scope="module")
def sphere():
    """A textured sphere 2 m around the rig's reference point, seen by the paper's rig at
    128 px (the renderer gives each camera its own exposure and noise): its surrogates as
    they come (``raw``) and gain-normalised, masks, and the images."""
    from gijax.render import render_fronto_plane

    rig = scale_rig(builtin_rig("paper-train"), SCALE)
    sample = render_fronto_plane(rig, TRUE_DISTANCE, seed=7, pano=PANO)
    masks = np.asarray(sample["masks"], np.float32)
    sur, smask = surrogate_images(rig, jnp.asarray(sample["images"]), jnp.asarray(masks), SPANO)
    return {"rig": model_rig(rig), "raw": sur[None],
            "surrogates": normalize_gain(sur[None], smask[None]), "masks": smask[None],
            "images": sample["images"], "raw_masks": masks}


def _photo(sphere, distance, which="surrogates"):
    inv = jnp.full((1, *PANO.shape), 1.0 / distance, jnp.float32)
    return float(photometric_loss(sphere[which], sphere["masks"], sphere["rig"], inv,
                                  PANO, SPANO))


def test_photometric_loss_is_least_at_the_true_distance(sphere):
    at_truth = _photo(sphere, TRUE_DISTANCE)
    others = {d: _photo(sphere, d) for d in (1.0, 1.5, 3.0, 6.0)}
    # Near agreement at the truth (resampling and sensor noise; the Charbonnier floor is
    # 1e-3), clear disagreement off it, growing with the error on each side.
    assert at_truth < 0.013, at_truth
    assert all(v > 1.4 * at_truth for v in others.values()), (at_truth, others)
    assert others[1.0] > others[1.5] and others[6.0] > others[3.0], others
    # Without the gain normalisation the cameras' exposures dominate every distance.
    raw = [_photo(sphere, d, "raw") for d in (1.5, TRUE_DISTANCE, 3.0)]
    assert min(raw) > 4 * at_truth and max(raw) < 1.1 * min(raw), raw


def _smoothness_by_hand(inv, img, scale):
    """Loops over pixel pairs: horizontal pairs wrap around, vertical ones do not."""
    b, h, w = inv.shape
    total_x = total_y = 0.0
    for s in range(b):
        n = inv[s] / inv[s].mean()
        for r in range(h):
            for c in range(w):
                c2 = (c + 1) % w
                total_x += abs(n[r, c2] - n[r, c]) * np.exp(
                    -scale * np.mean(np.abs(img[s, r, c2] - img[s, r, c])))
                if r + 1 < h:
                    total_y += abs(n[r + 1, c] - n[r, c]) * np.exp(
                        -scale * np.mean(np.abs(img[s, r + 1, c] - img[s, r, c])))
    return total_x / (b * h * w) + total_y / (b * (h - 1) * w)


def test_smoothness_is_zero_on_constant_maps_and_matches_a_hand_computation():
    rng = np.random.default_rng(0)
    img = rng.uniform(0, 1, (2, 3, 4, 3))
    const = np.full((2, 3, 4), 0.7)
    assert float(edge_aware_smoothness(jnp.asarray(const), jnp.asarray(img))) == 0.0
    inv = rng.uniform(0.1, 2.0, (2, 3, 4))
    with jax.enable_x64(True):
        got = float(edge_aware_smoothness(jnp.asarray(inv), jnp.asarray(img), 3.0))
    np.testing.assert_allclose(got, _smoothness_by_hand(inv, img, 3.0), rtol=1e-10)
    # Scale-free: a uniformly nearer scene costs the same; colour edges lower the cost.
    np.testing.assert_allclose(float(edge_aware_smoothness(jnp.asarray(5 * inv),
                                                           jnp.asarray(img), 3.0)), got,
                               rtol=1e-6)
    flat = float(edge_aware_smoothness(jnp.asarray(inv), jnp.zeros_like(jnp.asarray(img)), 3.0))
    assert flat > got


def test_teacher_term_is_masked_and_its_confidence_rejects_wrong_or_invalid_estimates(sphere):
    rng = np.random.default_rng(1)
    inv = jnp.asarray(rng.uniform(0.2, 1.0, (1, 4, 5)), jnp.float32)
    teach = jnp.asarray(rng.uniform(0.2, 1.0, (1, 4, 5)), jnp.float32)
    mask = jnp.asarray(rng.uniform(size=(1, 4, 5)) > 0.5, jnp.float32)
    loss = float(teacher_loss(inv, teach, mask))
    # Where the mask does not trust the teacher its values (even NaN) change nothing.
    other = jnp.where(mask > 0, teach, jnp.nan)
    assert float(teacher_loss(inv, other, mask)) == loss
    x = 96.0 * np.abs(np.asarray(inv - teach))
    ref = np.where(x < 1, 0.5 * x**2, x - 0.5)[np.asarray(mask) > 0].mean()
    np.testing.assert_allclose(loss, ref, rtol=1e-5)
    assert float(teacher_loss(inv, teach, jnp.zeros_like(mask))) == 0.0
    # Confidence on the sphere: the true distance is trusted where two cameras see it, a wrong
    # one mostly not, an invalid estimate never.
    s = sphere
    ones = jnp.ones((1, *PANO.shape), bool)

    def trusted(d, valid=ones, thr=0.012):
        t = jnp.full((1, *PANO.shape), 1.0 / d, jnp.float32)
        return np.asarray(teacher_confidence(s["surrogates"], s["masks"], s["rig"], t, valid,
                                             PANO, SPANO, thr))

    right, wrong = trusted(TRUE_DISTANCE, thr=0.012), trusted(0.9, thr=0.012)
    assert right.mean() > 0.5 and wrong.mean() < 0.5 * right.mean(), (right.mean(), wrong.mean())
    half = np.zeros((1, *PANO.shape), bool)
    half[:, :, :32] = True
    assert trusted(TRUE_DISTANCE, jnp.asarray(half))[:, :, 32:].max() == 0.0


def test_objective_never_reads_labels_and_weighs_its_terms(sphere):
    inv = jnp.full((1, *PANO.shape), 0.45, jnp.float32)
    batch = {"surrogates": sphere["raw"], "masks": sphere["masks"],
             "teacher_inv": jnp.full((1, *PANO.shape), 0.5), "teacher_mask": jnp.ones((1, *PANO.shape))}
    obj = LabelFree(photometric=1.0, smoothness=0.5, teacher=0.1)
    terms = label_free_terms(obj, inv, batch, sphere["rig"], PANO)
    # A batch with labels, of any value, gives the same numbers (there is no label to read).
    for dist in (np.full((1, *PANO.shape), 2.0), np.random.default_rng(2).uniform(
            0.5, 9, (1, *PANO.shape))):
        labelled = dict(batch, distance=jnp.asarray(dist), valid=jnp.ones((1, *PANO.shape), bool))
        again = label_free_terms(obj, inv, labelled, sphere["rig"], PANO)
        assert {k: float(v) for k, v in again.items()} == {k: float(v) for k, v in terms.items()}
    # The photometric term is the loss on the gain-normalised surrogates.
    np.testing.assert_allclose(float(terms["photometric"]), _photo(sphere, 1 / 0.45), rtol=1e-5)
    assert float(terms["smoothness"]) == 0.0        # a constant map
    np.testing.assert_allclose(float(terms["loss"]), float(terms["photometric"])
                               + 0.1 * float(terms["teacher"]), rtol=1e-6)
    with pytest.raises(ValueError, match="every weight is 0"):
        LabelFree(photometric=0.0, smoothness=0.0)
    with pytest.raises(ValueError, match="'teacher' must be a number >= 0"):
        LabelFree(teacher=-1.0)


# ------------------------------------------------------------------- adaptation runs

@pytest.fixture(scope="module")
def setup(tmp_path_factory, sphere):
    """A tiny bundle, frame folders of the sphere (PNG per camera) and a dataset of it whose
    labels are deliberately wrong."""
    from gijax.candidates.closed_form import gi_candidates
    from gijax.data import write_dataset
    from gijax.model import create_model
    from gijax.store.configs import CONFIG_FILE, run_config_document
    from gijax.train.bundle import save_bundle

    root = tmp_path_factory.mktemp("adapt")
    model = create_model(TINY, seed=3)
    model.eval()
    cand = np.asarray(gi_candidates(8, 0.5, 100.0), np.float64)
    (root / CONFIG_FILE).write_text(json.dumps(run_config_document(
        {"preset": "G8-cpu", "seed": 3}, TINY, cand, "paper-train")))
    bundle = save_bundle(model, root / CONFIG_FILE, root / "bundle", {"note": "tiny"})
    frames = []
    for f in range(2):
        folder = root / f"frame{f}"
        folder.mkdir()
        images = np.roll(sphere["images"], 3 * f, axis=2)   # two different frames
        for name, im in zip(builtin_rig("paper-train").names, images):
            cv2.imwrite(str(folder / f"{name}.png"), np.ascontiguousarray(im[..., ::-1]))
        frames.append(str(folder))
    rig = scale_rig(builtin_rig("paper-train"), SCALE)
    write_dataset(root / "data", lambda i: {
        "images": np.roll(sphere["images"], 3 * i, axis=2),
        "distances": np.full((3, 128, 128), 2.0, np.float32),
        "masks": np.asarray(sphere["raw_masks"] > 0, np.uint8),
        "pano_distance": np.full(TINY.output_hw, 9.0 + i, np.float32)},
        rig, PANO, num_samples=2)
    return {"root": root, "bundle": bundle, "frames": frames, "data": str(root / "data")}


def _weights(path):
    with np.load(path / "weights.npz") as z:
        return {k: z[k] for k in z.files}


def test_adaptation_resumes_to_the_uninterrupted_state_and_writes_a_loadable_bundle(setup):
    from gijax.store import load_model
    from gijax.store.bundles import read_provenance
    from gijax.train.rig_adaptation import adapt_network

    obj = LabelFree(photometric=1.0, smoothness=0.01)
    kw = dict(rig="paper-train", objective=obj, steps=4, lr=1e-3, batch_size=1, ckpt_every=2,
              progress=False, log=None)
    root = setup["root"]
    whole = adapt_network(setup["bundle"], setup["frames"], root / "whole", **kw)
    adapt_network(setup["bundle"], setup["frames"], root / "pieces", stop_at=2, **kw)
    pieces = adapt_network(setup["bundle"], setup["frames"], root / "pieces", **kw)
    assert whole.step == pieces.step == 4
    a, b, start = _weights(whole.bundle), _weights(pieces.bundle), _weights(setup["bundle"])
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-5, atol=1e-7, err_msg=k)
    assert any(not np.allclose(a[k], start[k]) for k in a), "the weights did not move"
    # The loss terms are logged, the loss is finite, each step once.
    lines = [json.loads(x) for x in (whole.work / "metrics.jsonl").read_text().splitlines()]
    steps = [r for r in lines if "loss" in r]
    assert [r["step"] for r in steps] == [1, 2, 3, 4]
    assert all(np.isfinite(r["loss"]) and "loss_photometric" in r and "loss_smoothness" in r
               and np.isfinite(r["grad_norm"]) and r["grad_norm"] > 0 for r in steps)
    # The bundle loads like any other, and says where it came from.
    model, mc, cand = load_model(str(whole.bundle))
    assert mc.output_hw == TINY.output_hw and len(cand) == 8
    prov = read_provenance(whole.bundle)
    assert prov["adapted"] is True and prov["adapted_from"] == str(setup["bundle"])
    assert prov["adapted_from_provenance"] == {"note": "tiny"}
    assert prov["frames"] == setup["frames"] and prov["objective"]["smoothness"] == 0.01
    assert prov["labels_used_for_loss"] is False


def test_dataset_labels_do_not_change_the_adaptation(setup, capsys):
    """The same frames as a dataset whose labels are wrong and a second copy with other labels:
    the adaptation is identical (the labels are never given to the objective); with the
    dataset as --val its labels give a score, logged as such. Also the command line."""
    from gijax.cli import main
    from gijax.data import write_dataset
    from gijax.data.reader import DatasetReader

    root = setup["root"]
    reader = DatasetReader(setup["data"])
    write_dataset(root / "data2", lambda i: dict(reader[i], pano_distance=np.full(
        TINY.output_hw, 0.6, np.float32)), reader.rig, PANO, num_samples=2)
    args = ["adapt", "--ckpt", str(setup["bundle"]), "--steps", "2", "--batch", "1",
            "--lr", "1e-3", "--no-progress"]
    assert main([*args, "--frames", setup["data"], "--out", str(root / "a")]) == 0
    assert main([*args, "--frames", str(root / "data2"), "--out", str(root / "b"),
                 "--val", setup["data"]]) == 0
    printed = capsys.readouterr().out
    assert "validation (labels of" in printed and "not used for adapting" in printed
    a, b = _weights(root / "a"), _weights(root / "b")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    lines = [json.loads(x) for x in (root / "b.adapt" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in lines if r.get("split") == "val"] == [0, 2]
    # Bad input: one line each.
    assert main([*args, "--frames", str(root / "nowhere"), "--out", str(root / "c")]) == 1
    assert "--frames" in capsys.readouterr().err
    assert main([*args, "--frames", setup["frames"][0], "--out", str(root / "c")]) == 1
    assert "give --rig" in capsys.readouterr().err
    assert main([*args, "--frames", setup["data"], "--out", str(root / "c"),
                 "--photometric", "0", "--smoothness", "0"]) == 1
    assert "every weight is 0" in capsys.readouterr().err
