"""Edges that real rigs reach: the baseline without a model, rigs that leave pixels unmatched,
images of another size, and the colour panorama."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from gijax.cli import main
from gijax.data.reader import DatasetReader
from gijax.geometry.layouts import builtin_rig, synthetic_camera
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import make_rig
from gijax.predict import fit_images, point_colours, write_prediction

# Compiled without XLA's optimisation passes (conftest's quick_compiles): these checks do
# not depend on them, and they dominate this module's time.
pytestmark = pytest.mark.usefixtures("quick_compiles")

SIZE = 64
FOV = 150.0     # degrees: the panorama's rim (90 degrees off the axis) is seen by no camera


def ring_rig(n=5, radius=0.3):
    """``n`` narrow-lens cameras on a ring, looking up, reference at the centre."""
    ang = 2.0 * np.pi * np.arange(n) / n
    pos = np.stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(n)], -1)
    cam = synthetic_camera(SIZE, focal=300.0 * SIZE / 1024, fov_deg=FOV)
    return make_rig([cam] * n, np.tile(np.eye(3), (n, 1, 1)), pos, np.zeros(3))


@pytest.fixture(scope="module")
def ring_data(tmp_path_factory):
    from gijax.data.rendered import render_dataset
    from gijax.io.rigfile import save_rig

    root = tmp_path_factory.mktemp("ring")
    render_dataset(ring_rig(), root / "data", 1, seed=1, pano=Panorama.hemisphere(16, 64),
                   style="indoor", progress=False)
    save_rig(ring_rig(), root / "ring.yaml")
    return root


def test_eval_rtss_on_a_five_camera_ring_needs_no_model_and_scores_holes(ring_data, tmp_path,
                                                                         capsys):
    data = str(ring_data / "data")
    out = tmp_path / "m.json"
    rc = main(["eval", "--method", "rtss", "--rtss-preset", "RS-E16", "--data", data,
               "--json", str(out)])
    err = capsys.readouterr().err
    assert rc == 0, err
    # The default list is named and counted at run time.
    assert "RS-E16's own list (16 even in inverse distance" in err
    # A progress bar over the samples, on stderr (RTSS runs take seconds a sample).
    n = len(DatasetReader(data))
    assert "eval RS-E16/rtss: 100%" in err and f"{n}/{n}" in err, err
    res = json.loads(out.read_text())
    assert res["run"] is None and len(res["candidates"]) == 16
    for key in ("mae", "rmse", "ssim"):
        assert math.isfinite(res[key]), (key, res)
    # The rim of the panorama lies outside every 150-degree lens: those labels are unmatched.
    assert 0.3 < res["coverage"] < 1.0
    assert res["mae"] < 0.5 and -1.0 <= res["ssim"] <= 1.0


def test_rtss_refuses_a_model_and_net_needs_one(ring_data, tmp_path, capsys):
    data = str(ring_data / "data")
    rc = main(["eval", "--method", "rtss", "--ckpt", "G16VV-cpu", "--data", data])
    assert rc == 1 and "drop --ckpt" in capsys.readouterr().err
    rc = main(["eval", "--data", data])
    assert rc == 1 and "--method learned needs --ckpt" in capsys.readouterr().err
    img = tmp_path / "a.png"
    cv2.imwrite(str(img), np.zeros((128, 128, 3), np.uint8))
    rc = main(["predict", "--method", "rtss", "--ckpt", "G16VV-cpu", "--rig", "paper-train",
               "--images", str(img), str(img), str(img), "--out", str(tmp_path / "o")])
    assert rc == 1 and "drop --ckpt" in capsys.readouterr().err
    # The estimate reads a learned model's probabilities: RTSS has none, and an ONNX file runs
    # the one it was exported with.
    rc = main(["predict", "--method", "rtss", "--estimate", "mode", "--rig", "paper-train",
               "--images", str(img), str(img), str(img), "--out", str(tmp_path / "o")])
    assert rc == 1 and "drop --estimate" in capsys.readouterr().err
    rc = main(["predict", "--backend", "onnx", "--ckpt", str(tmp_path / "m.onnx"), "--estimate",
               "mode", "--rig", "paper-train", "--images", str(img), str(img), str(img),
               "--out", str(tmp_path / "o")])
    assert rc == 1 and "exported with" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_fit_images_resizes_same_aspect_and_refuses_another():
    rig = builtin_rig("paper-train")                       # 1024 x 1024 cameras
    images = np.zeros((3, 256, 256, 3), np.uint8)
    images[:, :128] = 200                                  # top half bright
    notes = []
    run, out, masks = fit_images(rig, images, np.ones((3, 256, 256)), (64, 64), notes.append)
    assert out.shape == (3, 64, 64, 3) and masks.shape == (3, 64, 64)
    assert run.cameras[0].width == 64 and run.cameras[0].fx == pytest.approx(300.0 / 16)
    # Area averaging: rows wholly inside a half keep its value.
    assert np.all(out[:, :32] == 200) and np.all(out[:, 32:] == 0)
    assert notes and "resized to 64 x 64" in notes[0] and "256 x 256" in notes[0]
    # The baseline's branch: no resampling, the lenses rescaled to the images.
    notes.clear()
    run, out, _ = fit_images(rig, images, None, None, notes.append)
    assert out is images or np.shares_memory(out, images)
    assert run.cameras[0].width == 256 and run.cameras[0].cx == pytest.approx(127.5)
    assert "rescaled by 0.25" in notes[0]
    # Already the right size: nothing changes, nothing is said.
    notes.clear()
    run, _, _ = fit_images(rig, np.zeros((3, 1024, 1024, 3), np.uint8), None, None,
                           notes.append)
    assert run is rig and not notes
    with pytest.raises(ValueError, match=r"1024 x 1024.*found 200 x 256"):
        fit_images(rig, np.zeros((3, 200, 256, 3), np.uint8), None, (64, 64))


def test_colour_panorama_is_the_mean_over_the_cameras_that_see_each_point():
    rig = ring_rig(n=3)
    colours = np.array([[0.9, 0.1, 0.1], [0.1, 0.8, 0.2], [0.2, 0.3, 0.7]], np.float32)
    images = np.broadcast_to(colours[:, None, None], (3, SIZE, SIZE, 3))
    pano = Panorama.hemisphere(16, 64)
    got = point_colours(rig, images, None, np.full(pano.shape, 2.0, np.float32))
    # Independent construction: a point is in a camera's view when its angle from the camera's
    # axis (+z, identity rotations) is below half the field of view.
    h, w = pano.shape
    lon = -math.pi + 2 * math.pi * (np.arange(w) + 0.5) / w
    polar = (math.pi / 2) * (np.arange(h) + 0.5) / h
    lon, polar = np.meshgrid(lon, polar)
    points = 2.0 * np.stack([np.sin(polar) * np.cos(lon), -np.sin(polar) * np.sin(lon),
                             np.cos(polar)], -1)
    angles = []
    for i in range(3):
        v = points - np.asarray(rig.translations[i], np.float64)
        angles.append(np.degrees(np.arccos(v[..., 2] / np.linalg.norm(v, axis=-1))))
    angles = np.stack(angles)                                       # (3, H, W)
    seen = angles < FOV / 2
    count = seen.sum(0)
    want = np.einsum("nhw,nc->hwc", seen.astype(float), colours) / np.maximum(count, 1)[..., None]
    # Within a degree and a half of a rim the bilinear footprint straddles it: not compared.
    clear = np.all(np.abs(angles - FOV / 2) > 1.5, axis=0)
    assert (clear & (count == 3)).any() and (clear & (count > 0) & (count < 3)).any()
    assert (clear & (count == 0)).any()
    np.testing.assert_allclose(got[clear], want[clear], atol=2e-3)


def test_written_files_never_hold_inf_and_rtss_writes_rgb_without_uncertainty(tmp_path):
    rig = builtin_rig("paper-train")
    valid = np.ones((16, 64), bool)
    valid[0, :4] = False
    distance = np.full((16, 64), 3.0, np.float32)
    distance[1, 1] = np.inf                                 # a "valid" pixel at infinity
    distance[0, :4] = np.nan
    colour = np.full((16, 64, 3), 0.5, np.float32)
    result = {"distance": distance, "inv_distance": 1.0 / distance, "valid": valid,
              "colour": colour, "candidates": np.array([0.5, 1.0, 100.0])}
    paths = write_prediction(result, rig, tmp_path / "p")
    saved = np.load(paths["distance"])
    assert not np.isinf(saved).any() and np.isnan(saved[1, 1]) and np.isnan(saved[0, 0])
    assert not np.load(paths["valid"])[1, 1]
    assert "uncertainty_png" not in paths and not (tmp_path / "p" / "uncertainty.png").exists()
    rgb = cv2.imread(paths["rgb_png"])[..., ::-1]
    assert rgb.shape == (16, 64, 3)
    assert np.all(rgb[2:, 2:] == 128) and np.all(rgb[0, :4] == 0) and np.all(rgb[1, 1] == 0)
