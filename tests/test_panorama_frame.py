"""The rig's panorama frame: the automatic choice for rigs whose cameras share no axis, and every
place a panorama is made following it (sweep grids, candidates, rendering, rig and dataset
files, the learned model on the full sphere, RTSS and the CLI)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from gijax.cli.options import parse_up
from gijax.geometry.layouts import builtin_rig, synthetic_camera
from gijax.geometry.panorama import Panorama
from gijax.geometry.panorama_frame import (choose_panorama, frame_from_up, panorama_pixels,
                                           with_panorama_rotation)
from gijax.geometry.rig import make_rig
from gijax.geometry.rotations import axis_angle_to_matrix
from gijax.nn.presets import ModelConfig

SIZE = 48


def outward_ring(n=4, radius=0.08, fov=220.0):
    """``n`` wide lenses looking outward around a horizontal ring, expressed in camera 0's
    frame (x right, y down, z forward), as a calibration import gives it: up is -y there."""
    cam = synthetic_camera(SIZE, focal=SIZE / np.radians(fov), fov_deg=fov)
    rots, pos = [], []
    for k in range(n):
        a = 2 * np.pi * k / n
        # Turning about the camera-0 y axis (down) keeps every camera upright.
        fwd = np.array([np.sin(a), 0.0, np.cos(a)])
        down = np.array([0.0, 1.0, 0.0])
        right = np.cross(down, fwd)
        rots.append(np.stack([right, down, fwd], 1))
        pos.append(radius * fwd - radius * np.array([0.0, 0.0, 1.0]))
    return make_rig([cam] * n, np.stack(rots), np.stack(pos), np.zeros(3),
                    names=[f"cam{k}" for k in range(n)])


def test_paper_rigs_keep_their_hemisphere():
    for name in ("paper-train", "paper-test3"):
        choice = choose_panorama(builtin_rig(name))
        assert choice.coverage == "hemisphere"
        np.testing.assert_allclose(choice.rotation, np.eye(3))
        assert "within 0 deg" in choice.reason


def test_outward_ring_gets_the_full_sphere_with_the_pole_up():
    rig = outward_ring()
    choice = choose_panorama(rig)
    assert choice.coverage == "sphere"
    # Up is -y of camera 0's frame; longitude 0 faces camera 0.
    np.testing.assert_allclose(choice.rotation[:, 2], [0, -1, 0], atol=1e-6)
    np.testing.assert_allclose(choice.rotation[:, 0], [0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(np.linalg.det(choice.rotation), 1.0, atol=1e-6)
    assert "up axis [+0.00, -1.00, +0.00]" in choice.reason and "cam0" in choice.reason
    # Camera 0's axis lands on the middle column, on the equator of the full sphere.
    oriented = with_panorama_rotation(rig, choice.rotation)
    pano = choice.panorama((8, 32))
    assert pano.shape == (16, 32)
    px, ok = panorama_pixels(oriented, pano, jnp.asarray(rig.rotations[0][:, 2]))
    np.testing.assert_allclose(np.asarray(px), [15.5, 7.5], atol=1e-4)
    # Camera 1 (turned right, about +y = down) is to the right of camera 0.
    px1, _ = panorama_pixels(oriented, pano, jnp.asarray(rig.rotations[1][:, 2]))
    np.testing.assert_allclose(np.asarray(px1), [23.5, 7.5], atol=1e-4)


def test_explicit_up_and_coverage():
    rig = outward_ring()
    c = choose_panorama(rig, "hemisphere", up=parse_up("-y"))
    assert c.coverage == "hemisphere" and "given up axis" in c.reason
    np.testing.assert_allclose(c.rotation[:, 2], [0, -1, 0], atol=1e-6)
    c = choose_panorama(builtin_rig("paper-train"), "sphere")
    assert c.coverage == "sphere"
    np.testing.assert_allclose(parse_up("+x"), [1, 0, 0])
    np.testing.assert_allclose(parse_up("0, 0, -2"), [0, 0, -1])
    for bad in ("w", "1,2", "0,0,0", "up"):
        with pytest.raises(ValueError, match="up axis"):
            parse_up(bad)
    with pytest.raises(ValueError, match="coverage"):
        choose_panorama(rig, "dome")
    with pytest.raises(ValueError, match="must be a rotation"):
        with_panorama_rotation(rig, np.diag([1.0, 1.0, -1.0]))


def test_frame_from_up_is_a_rotation_with_the_given_pole():
    r = np.asarray(frame_from_up(jnp.array([0.0, 0.0, 2.0]), jnp.array([1.0, 1.0, 0.5])))
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-6)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-6)
    np.testing.assert_allclose(r[:, 2], [0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(r[:, 0], [2 ** -0.5, 2 ** -0.5, 0], atol=1e-6)


def _rotated(rig, q):
    """The whole rig turned by q: poses, reference and panorama frame."""
    return rig.replace(rotations=jnp.einsum("ij,njk->nik", q, rig.rotations),
                       translations=rig.translations @ q.T, reference=rig.reference @ q.T,
                       panorama_rotation=q @ rig.panorama_rotation)


def test_grids_and_candidates_follow_the_frame():
    """Turning the rig and its panorama frame together changes neither the sweep grids nor the
    rig-aware candidates: they follow the frame, not the rig's axes."""
    from gijax.candidates.rig_aware import rig_gi_candidates
    from gijax.sweep.grid import sweep_grid

    rig = builtin_rig("paper-train")
    q = axis_angle_to_matrix(jnp.array([0.3, -0.8, 0.5], jnp.float32))
    turned = _rotated(rig, q)
    cand = jnp.array([0.7, 1.5, 4.0, 20.0])
    cost, feat = Panorama.hemisphere(4, 16), Panorama.hemisphere(8, 32)
    px0, ok0 = sweep_grid(rig, cand, cost, feat)
    px1, ok1 = sweep_grid(turned, cand, cost, feat)
    assert np.array_equal(np.asarray(ok0), np.asarray(ok1))
    np.testing.assert_allclose(np.asarray(px1)[np.asarray(ok0)], np.asarray(px0)[np.asarray(ok0)],
                               atol=2e-3)
    c0 = np.asarray(rig_gi_candidates(rig, 8, 0.5, 100.0))
    c1 = np.asarray(rig_gi_candidates(turned, 8, 0.5, 100.0))
    np.testing.assert_allclose(c1, c0, rtol=1e-3)
    # Turning only the rig (the panorama frame left behind) does change the sweep.
    px2, _ = sweep_grid(turned.replace(panorama_rotation=rig.panorama_rotation), cand, cost, feat)
    assert np.abs(np.asarray(px2) - np.asarray(px0)).max() > 1.0


def test_render_and_rig_file_follow_the_frame(tmp_path):
    """A ball along camera 0's axis shows up in the middle column on the equator of the
    full-sphere label of an outward ring, and the frame survives the rig file and a dataset."""
    from gijax.data import DatasetReader
    from gijax.data.rendered import render_dataset
    from gijax.io.rigfile import load_rig, save_rig
    from gijax.render import render_scene
    from gijax.render.scene import sphere_scene

    rig = outward_ring()
    choice = choose_panorama(rig)
    rig = with_panorama_rotation(rig, choice.rotation)
    pano = choice.panorama((8, 32))
    ball = np.asarray(rig.rotations[0][:, 2]) * 2.0
    label = np.asarray(render_scene(rig, sphere_scene(ball, 0.3), 0, pano)["pano_distance"])
    row, col = np.unravel_index(np.argmin(label), label.shape)
    assert (row, col) in {(7, 15), (7, 16), (8, 15), (8, 16)}, (row, col)
    # Every pixel against the ray-sphere closed form, its ray built from the documented
    # convention (latitude from the pole, longitude towards -y) and the chosen frame.
    h, w = pano.shape
    lon = -np.pi + 2 * np.pi * (np.arange(w) + 0.5) / w
    polar = np.pi * (np.arange(h) + 0.5) / h
    lon, polar = np.meshgrid(lon, polar)
    rays = np.stack([np.sin(polar) * np.cos(lon), -np.sin(polar) * np.sin(lon), np.cos(polar)],
                    -1) @ choice.rotation.T
    along = rays @ ball
    disc = along ** 2 - ball @ ball + 0.3 ** 2
    hit = (disc > 0) & (along > 0)
    want = along - np.sqrt(np.where(hit, disc, 0.0))
    assert hit.sum() >= 2
    np.testing.assert_allclose(label[hit], want[hit], rtol=1e-4)
    assert np.all(label[~hit] > 1e3)                 # sky everywhere else

    path = save_rig(rig, tmp_path / "ring.yaml")
    assert "panorama_rotation" in path.read_text()
    back = load_rig(path)
    np.testing.assert_allclose(np.asarray(back.panorama_rotation), choice.rotation, atol=1e-6)
    render_dataset(rig, tmp_path / "data", 1, seed=2, pano=pano, progress=False)
    reader = DatasetReader(tmp_path / "data")
    np.testing.assert_allclose(np.asarray(reader.rig.panorama_rotation), choice.rotation,
                               atol=1e-6)
    assert reader.pano == pano


TINY = ModelConfig(
    name="tiny", num_candidates=8, candidates="ev", loss="volume", features="plain",
    cost_volume="variance", feature_channels=4, feature_blocks=(1, 1), unet_in=4, unet_base=4,
    surrogate_hw=(16, 64), cost_hw=(8, 32), output_hw=(16, 64), image_scale=1.0)


def test_learned_model_runs_on_the_full_sphere_and_says_it_was_trained_on_less(quick_compiles):
    from gijax.model import create_model, model_panorama
    from gijax.predict import predict
    from gijax.render import render_sample

    rig = outward_ring()
    choice = choose_panorama(rig)
    rig = with_panorama_rotation(rig, choice.rotation)
    sphere = model_panorama(TINY, "sphere")
    assert sphere.shape == (32, 64) and sphere.lat_max > 1.5
    sample = render_sample(rig, 3, pano=sphere)
    notes = []
    out = predict(create_model(TINY), rig, sample["images"], None,
                  np.geomspace(0.5, 100.0, 8), log=notes.append, pano=sphere)
    assert out["inv_distance"].shape == (32, 64) and out["panorama"] == sphere
    assert any("trained on the hemisphere" in n and "sphere" in n for n in notes), notes
    # Both poles are outside every camera's 220-degree cone only near the poles: most of the
    # sphere is seen by two cameras.
    assert 0.3 < out["valid"].mean() < 1.0
    with pytest.raises(ValueError, match="divisible by 16"):
        predict(create_model(TINY), rig, sample["images"], None, np.geomspace(0.5, 100.0, 8),
                pano=Panorama.sphere(24, 64))


def test_training_follows_the_labels_coverage():
    from gijax.train.config import TrainConfig
    from gijax.train.entry import fit_panorama

    class Labels:
        pano = Panorama.sphere(64, 128)      # G16VV-cpu's 32 x 128 hemisphere, doubled

    cfg = TrainConfig(preset="G16VV-cpu")
    notes = []
    cfg2, mc = fit_panorama(cfg, Labels(), log=notes.append)
    assert mc.panorama == "sphere" and mc.output_hw == (64, 128) and mc.cost_hw == (32, 64)
    assert "cover the sphere" in notes[0]
    Labels.pano = Panorama.hemisphere(40, 160)
    with pytest.raises(ValueError, match="40 x 160 panoramas but model 'G16VV-cpu' outputs"):
        fit_panorama(cfg, Labels())


def test_export_records_its_panorama():
    from gijax.export.onnx_export import export_metadata, export_panorama

    rig = outward_ring()
    choice = choose_panorama(rig)
    rig = with_panorama_rotation(rig, choice.rotation)
    pano = Panorama.sphere(32, 64)
    meta = export_metadata(TINY, rig, np.geomspace(0.5, 100, 8), False, False, pano)
    assert export_panorama(meta, TINY) == pano
    doc = json.loads(meta["panorama"])
    np.testing.assert_allclose(doc["rotation_panorama_to_rig"], choice.rotation, atol=1e-6)
    assert export_panorama({}, TINY) == Panorama.hemisphere(16, 64)


def test_predict_rtss_on_an_outward_ring_writes_the_full_sphere(tmp_path, capsys):
    from gijax.cli import main
    from gijax.io.rigfile import save_rig
    from gijax.render import render_sample

    rig = outward_ring()
    rig_file = save_rig(rig, tmp_path / "ring.yaml")
    choice = choose_panorama(rig)
    sample = render_sample(with_panorama_rotation(rig, choice.rotation), 4,
                           pano=Panorama.sphere(16, 32))
    images = []
    for i, im in enumerate(sample["images"]):
        images.append(str(tmp_path / f"c{i}.png"))
        cv2.imwrite(images[-1], np.ascontiguousarray(np.asarray(im)[..., ::-1]))
    out = tmp_path / "o"
    rc = main(["predict", "--method", "rtss", "--rtss-preset", "RS-E16", "--rig", str(rig_file),
               "--images", *images, "--panorama-size", "16x32", "--out", str(out)])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    assert "panorama: sphere (180 deg of latitude), 16x32" in printed
    assert np.load(out / "distance.npy").shape == (16, 32)
    meta = json.loads((out / "prediction.json").read_text())
    assert meta["panorama"]["coverage"] == "sphere"
    np.testing.assert_allclose(meta["panorama"]["rotation_panorama_to_rig"], choice.rotation,
                               atol=1e-6)
    assert cv2.imread(str(out / "rgb.png")).shape == (16, 32, 3)


def test_readme_example_rig_imports_as_a_full_sphere_ring(tmp_path, capsys):
    """The files of the README's "Your own rig" walkthrough import as it shows."""
    from gijax.cli import main
    from gijax.io.rigfile import load_rig

    ex = Path(__file__).resolve().parents[1] / "docs" / "examples" / "four_fisheye_ring"
    masks = [str(ex / f"mask_cam{k}.png") for k in range(4)]
    rc = main(["rig", "import", str(ex / "calibration.json"), "--masks", *masks, "--out",
               str(tmp_path / "rig.yaml")])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    assert "panorama: sphere (180 deg of latitude), 320x640" in printed
    assert "pole is the rig's up axis [+0.00, -1.00, +0.00]" in printed
    rig = load_rig(tmp_path / "rig.yaml")
    assert rig.num_cameras == 4 and all(m is not None for m in rig.masks)
    np.testing.assert_allclose(np.asarray(rig.reference), [0.0, 0.0, -0.05], atol=1e-6)
    np.testing.assert_allclose(np.asarray(rig.panorama_rotation)[:, 2], [0, -1, 0], atol=1e-6)
    for k in range(4):
        assert cv2.imread(str(ex / f"cam{k}.png")).shape == (256, 256, 3)
