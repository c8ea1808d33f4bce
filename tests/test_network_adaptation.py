"""Label-free adaptation of a trained network to a rig (``gijax adapt``): the loss terms against
independent references, the objective never reading labels, and a short adaptation run that
resumes exactly and writes a bundle every ``--ckpt`` loads."""

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

pytestmark = pytest.mark.usefixtures("quick_compiles", "compile_cache")


@pytest.fixture(scope="module")
def compile_cache():
    """The adaptation runs compile the same training step: the persistent cache (the one the
    training tests share) compiles it once."""
    from conftest import persistent_compile_cache
    from test_train_faults import CACHE

    yield from persistent_compile_cache(CACHE)

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
    with pytest.raises(ValueError, match=r"LabelFree\.teacher must be a finite number >= 0 "
                                         r"\(a weight\); found -1"):
        LabelFree(teacher=-1.0)


def test_occlusion_hides_points_behind_nearer_ones_of_the_same_sample_only(sphere):
    """Two samples: a far map (4 m) with a near patch (0.5 m) and the far map alone. With the
    occlusion test each camera's weights on the first are its weights without it times the
    points' visibility from its centre (background points behind the patch hidden from the
    cameras off the reference point); the second sample's weights are unchanged (the first
    sample's patch hides nothing in it); the objective records the margin and rejects a bad
    one."""
    from gijax.geometry.panorama_frame import panorama_rays
    from gijax.geometry.visibility import visible_from
    from gijax.train.unlabeled import camera_samples

    rig = sphere["rig"]
    inv = np.full((2, *PANO.shape), 0.25, np.float32)
    inv[0, 2:6, 24:36] = 2.0
    sur = jnp.concatenate([sphere["surrogates"]] * 2)
    masks = jnp.concatenate([sphere["masks"]] * 2)
    _, plain = (np.asarray(x) for x in camera_samples(sur, masks, rig, jnp.asarray(inv), PANO,
                                                      SPANO))
    _, seen = (np.asarray(x) for x in camera_samples(sur, masks, rig, jnp.asarray(inv), PANO,
                                                     SPANO, occlusion=0.05))
    pts = np.asarray(rig.reference) + (1.0 / inv[0])[..., None] * np.asarray(
        panorama_rays(rig, PANO, jnp.float32))
    hidden = 0
    for k in range(rig.num_cameras):
        vis = np.asarray(visible_from(jnp.asarray(pts, jnp.float32), rig.translations[k],
                                      PANO.width, 0.05))
        np.testing.assert_allclose(seen[k, 0], plain[k, 0] * vis, rtol=1e-6, atol=1e-7)
        hidden += int(((plain[k, 0] > 0.5) & (vis == 0)).sum())
    assert hidden > 20          # 46 of the background pixels behind the patch, over the cameras
    np.testing.assert_allclose(seen[:, 1], plain[:, 1], rtol=1e-6, atol=1e-7)
    batch = {"surrogates": sur, "masks": masks}
    on = label_free_terms(LabelFree(), jnp.asarray(inv), batch, rig, PANO)    # the default
    off = label_free_terms(LabelFree(occlusion=0.0), jnp.asarray(inv), batch, rig, PANO)
    assert float(on["photometric"]) != float(off["photometric"])
    with pytest.raises(ValueError, match=r"LabelFree\.occlusion must be a margin in \[0, 1\) "
                                         r"\(0: off\); found 1\.5"):
        LabelFree(occlusion=1.5)


def test_a_run_stored_before_the_occlusion_test_resumes_only_as_it_ran(tmp_path):
    """A run folder whose stored objective predates ``occlusion`` compared every camera: it
    reads back with occlusion 0, resuming it with the new default is refused, and with
    ``--occlusion 0`` it continues."""
    import dataclasses

    from gijax.candidates.closed_form import gi_candidates
    from gijax.store.configs import CONFIG_FILE, run_config_document
    from gijax.train.config import load_run_config
    from gijax.train.run_folder import check_resumable

    stored = {k: v for k, v in LabelFree().to_dict().items() if k != "occlusion"}
    cand = np.asarray(gi_candidates(8, 0.5, 100.0), np.float64)
    (tmp_path / CONFIG_FILE).write_text(json.dumps(run_config_document(
        {"preset": "G8-cpu", "seed": 3, "label_free": stored, "batch_norm": "frozen"}, TINY,
        cand, "paper-train")))
    old, mc, _ = load_run_config(tmp_path)
    assert old.label_free == {**stored, "occlusion": 0.0}
    with pytest.raises(ValueError, match=r"'occlusion': 0\.0.*'occlusion': 0\.05"):
        check_resumable(tmp_path, dataclasses.replace(old, label_free=LabelFree().to_dict()), mc)
    check_resumable(tmp_path, dataclasses.replace(
        old, label_free=LabelFree(occlusion=0.0).to_dict()), mc)


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


def test_frame_folders_are_resized_to_the_model_and_carry_no_labels(setup):
    from gijax.train.rig_adaptation import adaptation_rig, frame_arrays

    rig, text, calibrated = adaptation_rig(setup["frames"], "paper-train", TINY.panorama)
    assert calibrated and text == "paper-train"
    run_rig, arrays, labels, images, _ = frame_arrays(setup["frames"], rig, TINY, calibrated)
    # The calibrated 1024 px rig at the model's image scale 1/16; the 128 px frames resized.
    assert (run_rig.cameras[0].height, run_rig.cameras[0].width) == (64, 64)
    assert images.shape == (2, 3, 64, 64, 3) and labels == setup["frames"]
    assert arrays["surrogates"].shape == (2, 3, *TINY.surrogate_hw, 3)
    assert np.isnan(arrays["distance"]).all() and not arrays["valid"].any()
    # A dataset brings its rig and its size; its labels are not carried either.
    rig, _, calibrated = adaptation_rig([setup["data"]], None, TINY.panorama)
    assert not calibrated and rig.cameras[0].width == 128
    _, arrays, labels, _, _ = frame_arrays([setup["data"]], rig, TINY, calibrated)
    assert labels == [f"{setup['data']}#0", f"{setup['data']}#1"]
    assert np.isnan(arrays["distance"]).all() and not arrays["valid"].any()


def test_adaptation_ignores_labels_resumes_exactly_and_writes_a_loadable_bundle(setup, capsys):
    """One run on a dataset whose labels are wrong, uninterrupted; another on a copy with
    other labels, stopped after one step and finished by the command (with the first dataset
    as --val): the same weights (the labels never reach the objective, and the resumed run
    continues exactly); the bundle loads like any other and says where it came from."""
    from gijax.cli import main
    from gijax.data import write_dataset
    from gijax.data.reader import DatasetReader
    from gijax.store import load_model
    from gijax.store.bundles import read_provenance
    from gijax.train.rig_adaptation import adapt_network

    root = setup["root"]
    reader = DatasetReader(setup["data"])
    write_dataset(root / "data2", lambda i: dict(reader[i], pano_distance=np.full(
        TINY.output_hw, 0.6, np.float32)), reader.rig, PANO, num_samples=2)
    obj = LabelFree(photometric=1.0, smoothness=0.01)
    kw = dict(objective=obj, steps=2, lr=1e-3, batch_size=1, ckpt_every=1, progress=False,
              log=None)
    whole = adapt_network(setup["bundle"], [setup["data"]], root / "whole", **kw)
    adapt_network(setup["bundle"], [str(root / "data2")], root / "pieces", stop_at=1, **kw)
    args = ["adapt", "--ckpt", str(setup["bundle"]), "--steps", "2", "--batch", "1",
            "--lr", "1e-3", "--ckpt-every", "1", "--no-progress"]
    assert main([*args, "--frames", str(root / "data2"), "--out", str(root / "pieces"),
                 "--val", setup["data"]]) == 0
    printed = capsys.readouterr().out
    assert "validation (labels of" in printed and "not used for adapting" in printed
    a, b, start = _weights(whole.bundle), _weights(root / "pieces"), _weights(setup["bundle"])
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-5, atol=1e-7, err_msg=k)
    assert any(not np.allclose(a[k], start[k]) for k in a), "the weights did not move"
    # Each step's loss and its terms logged once; the validation score logged as such.
    lines = [json.loads(x) for x in (root / "pieces.adapt" / "metrics.jsonl").read_text()
             .splitlines()]
    steps = [r for r in lines if "loss" in r]
    assert [r["step"] for r in steps] == [1, 2]
    assert all(np.isfinite(r["loss"]) and "loss_photometric" in r and "loss_smoothness" in r
               and np.isfinite(r["grad_norm"]) and r["grad_norm"] > 0 for r in steps)
    assert [r["step"] for r in lines if r.get("split") == "val"] == [2]
    # The bundle loads like any other, and says where it came from.
    model, mc, cand = load_model(str(whole.bundle))
    assert mc.output_hw == TINY.output_hw and len(cand) == 8
    prov = read_provenance(whole.bundle)
    assert prov["adapted"] is True and prov["adapted_from"] == str(setup["bundle"])
    assert prov["adapted_from_provenance"] == {"note": "tiny"}
    assert prov["frames"] == [f"{setup['data']}#0", f"{setup['data']}#1"]
    assert prov["objective"]["smoothness"] == 0.01 and prov["labels_used_for_loss"] is False
    # Bad input: one line each, before any work.
    fails = [(["--frames", str(root / "nowhere")], "--frames"),
             (["--frames", setup["frames"][0]], "give --rig"),
             (["--frames", setup["data"], "--photometric", "0", "--smoothness", "0"],
              "every weight is 0"),
             (["--frames", setup["data"], "--batch", "3"], "larger than the 2 frame(s)")]
    for extra, words in fails:
        assert main([*args[:-5], "--no-progress", *extra, "--out", str(root / "c")]) == 1
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1, err
