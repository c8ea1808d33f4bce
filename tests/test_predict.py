"""Inference from raw fisheye images, the output files, and the ``gijax predict`` command."""

import dataclasses
import json
import math

import cv2
import numpy as np
import pytest

from gijax.cli import main
from gijax.geometry.layouts import builtin_rig
from gijax.model import create_model
from gijax.nn.presets import ModelConfig
from gijax.predict import predict, write_prediction

TINY = ModelConfig(
    name="tiny-variance", num_candidates=8, candidates="gi", loss="volume", features="spherical",
    cost_volume="variance", feature_channels=4, feature_blocks=(1, 1), unet_in=4, unet_base=4,
    surrogate_hw=(32, 128), cost_hw=(8, 32), output_hw=(16, 64), image_scale=1 / 16)
G8 = [0.5, 0.60103325, 0.73863074, 0.94007016, 1.26849604, 1.91086214, 3.77357055, 100.0]
RGB = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], np.uint8)


pytestmark = pytest.mark.usefixtures("quick_compiles")


@pytest.fixture(scope="module")
def setup():
    rig = builtin_rig("paper-train")
    model = create_model(TINY, seed=0)
    # One flat colour per camera: each point's colour says which camera it was taken from.
    images = np.broadcast_to(RGB[:, None, None], (3, 64, 64, 3)).copy()
    return rig, model, images, predict(model, rig, images, None, G8)


def np_rays(h, w):
    lon = -math.pi + 2 * math.pi * (np.arange(w) + 0.5) / w
    polar = (math.pi / 2) * (np.arange(h) + 0.5) / h
    lon, polar = np.meshgrid(lon, polar)
    # Longitude grows towards -y (the common equirectangular layout, docs/geometry.md).
    return np.stack([np.sin(polar) * np.cos(lon), -np.sin(polar) * np.sin(lon), np.cos(polar)],
                    -1)


def read_ply(path):
    data = open(path, "rb").read()
    head, body = data.split(b"end_header\n", 1)
    lines = head.decode().splitlines()
    assert lines[:2] == ["ply", "format binary_little_endian 1.0"]
    n = int(lines[2].split()[-1])
    rec = np.frombuffer(body, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"),
                                     ("g", "u1"), ("b", "u1")], count=n)
    assert len(body) == n * 15
    return np.stack([rec["x"], rec["y"], rec["z"]], -1), np.stack([rec["r"], rec["g"], rec["b"]],
                                                                  -1)


def test_predict_outputs(setup):
    rig, model, images, out = setup
    assert out["distance"].shape == (16, 64) and out["prob"].shape == (8, 16, 64)
    assert np.all(out["distance"] >= 0.5 - 1e-4) and np.all(out["distance"] <= 100.0 + 1e-2)
    np.testing.assert_allclose(out["inv_distance"] * out["distance"], 1.0, rtol=1e-5)
    assert np.all(out["entropy"] >= 0) and np.all(out["entropy"] <= math.log(8) + 1e-5)
    # Each colour is the mean over the cameras that see the point: with one flat colour per
    # camera, the mean of one of the 7 non-empty camera subsets (or black, seen by none).
    # Bilinear samples at a mask's edge blend towards black, so those pixels are left aside.
    col = out["colour"] * 255
    subsets = [np.mean(RGB[[i for i in range(3) if k >> i & 1]], 0) for k in range(1, 8)]
    near = [np.all(np.abs(col - c) < 0.5, axis=-1) for c in subsets + [np.zeros(3)]]
    hits = np.any(near, axis=0)
    assert hits.mean() > 0.95
    assert near[6].mean() > 0.5 and np.any(near[:6], axis=(1, 2)).sum() >= 2
    assert 0.3 < out["valid"].mean() <= 1.0


def test_full_size_images_are_resized_for_the_model(setup):
    rig, model, images, out = setup
    big = np.broadcast_to(RGB[:, None, None], (3, 1024, 1024, 3))
    notes = []
    out_big = predict(model, rig, big, None, G8, log=notes.append)
    np.testing.assert_allclose(out_big["distance"], out["distance"], rtol=1e-5)
    assert notes == ["note: images 1024 x 1024 resized to 64 x 64 (the rig's 1024 x 1024 "
                     "scaled by 0.0625) for the model"]
    # The colour panorama is sampled from the images the cameras gave, at the resolution they
    # support: focal 300 px per radian against 16 rows over 90 degrees (10.2 per radian) is 29
    # times finer, capped at 8; the 64-px images support round(18.75 / 10.19) = 2.
    assert out["rgb"].shape == (32, 128, 3) and out["rgb_valid"].shape == (32, 128)
    assert out_big["rgb"].shape == (128, 512, 3)
    col = out_big["rgb"][out_big["rgb_valid"]] * 255
    subsets = [np.mean(RGB[[i for i in range(3) if k >> i & 1]], 0) for k in range(1, 8)]
    near = np.any([np.all(np.abs(col - c) < 0.5, axis=-1) for c in subsets], axis=0)
    assert near.mean() > 0.95
    # Another size of the same aspect is resized too (here enlarged).
    out_mid = predict(model, rig, np.broadcast_to(RGB[:, None, None], (3, 48, 48, 3)), None, G8)
    np.testing.assert_allclose(out_mid["distance"], out["distance"], rtol=1e-5)


def test_predict_rejects_bad_input(setup):
    rig, model, images, _ = setup
    cases = [
        ((images[:2], None, G8), "3 cameras but 2 images"),
        ((images[:, :50], None, G8), "images must be 1024 x 1024"),
        ((np.concatenate([images, images[..., :1]], -1), None, G8), "3 \\(RGB\\) channels"),
        ((images, np.ones((3, 64, 60)), G8), "masks must have shape"),
        ((images, None, G8[:7]), "needs 8 candidates"),
        ((images, None, G8[::-1]), "ascending"),
        ((images, None, [-1.0] + G8[1:]), "> 0 m|positive"),
    ]
    for args, msg in cases:
        with pytest.raises(ValueError, match=msg):
            predict(model, rig, *args)


def test_written_files(setup, tmp_path):
    rig, _, _, out = setup
    paths = write_prediction(out, rig, tmp_path / "pred", title="test")
    dist = np.load(paths["distance"])
    # Invalid pixels are NaN in the file (the convention of every method's output).
    want_dist = np.where(out["valid"], out["distance"], np.nan).astype(np.float32)
    assert dist.dtype == np.float32 and np.array_equal(dist, want_dist, equal_nan=True)
    np.testing.assert_array_equal(np.load(paths["valid"]), out["valid"])
    for key in ("inverse_distance_png", "uncertainty_png"):
        png = cv2.imread(paths[key])
        assert png is not None and png.shape[1] >= 600 and png.shape[0] > 200
        # The colour bar: a row with a long run of distinct colours below the panorama.
        assert max(len(np.unique(row.reshape(-1, 3), axis=0)) for row in png) > 100
    pts, cols = read_ply(paths["points"])
    keep = out["valid"] & (out["distance"] <= 100.0)
    want = np.asarray(rig.reference) + out["distance"][..., None] * np_rays(16, 64)
    assert len(pts) == keep.sum() > 0
    np.testing.assert_allclose(pts, want[keep], rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(cols, (out["colour"][keep] * 255 + 0.5).astype(np.uint8))
    meta = json.loads((tmp_path / "pred" / "prediction.json").read_text())
    assert meta["points"] == len(pts) and np.allclose(meta["candidates_m"], G8)
    assert meta["points_left_out"]["pixels"] == int(out["valid"].sum()) - keep.sum()
    assert "beyond 100 m" in meta["points_left_out"]["reason"]
    rgb = cv2.imread(paths["rgb_png"])
    assert rgb.shape == out["rgb"].shape
    want_rgb = np.where(out["rgb_valid"][..., None], out["rgb"], 0.0)
    np.testing.assert_array_equal(rgb[..., ::-1], np.clip(want_rgb * 255 + 0.5, 0, 255).astype(
        np.uint8))


def test_cli(tmp_path, capsys, monkeypatch):
    files = []
    for i, c in enumerate(RGB):
        p = tmp_path / f"cam{i}.png"
        cv2.imwrite(str(p), np.broadcast_to(c[::-1], (64, 64, 3)).copy())  # written as BGR
        files.append(str(p))
    masks = []
    for i in range(3):
        p = tmp_path / f"mask{i}.png"
        m = np.full((64, 64), 255, np.uint8)
        m[40:, 20:30] = 0
        cv2.imwrite(str(p), m)
        masks.append(str(p))
    cfg = tmp_path / "tiny.json"
    cfg.write_text(json.dumps(dataclasses.asdict(TINY)))
    cand = tmp_path / "cand.txt"
    cand.write_text("\n".join(str(c * 1.5) for c in G8))
    out = tmp_path / "out"
    rc = main(["predict", "--preset", str(cfg), "--rig", "paper-train", "--images", *files,
               "--masks", *masks, "--candidates", str(cand), "--out", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "UNTRAINED tiny-variance" in text
    meta = json.loads((out / "prediction.json").read_text())
    np.testing.assert_allclose(meta["candidates_m"], np.array(G8) * 1.5)
    assert "UNTRAINED" in meta["title"]
    dist = np.load(out / "distance.npy")
    assert dist.shape == (16, 64) and np.nanmin(dist) >= 0.75 - 1e-4
    assert (out / "points.ply").stat().st_size > 100
    # The colour panorama, at the 2x finer resolution the 64-px cameras support (validity
    # upsampled by nearest neighbour): flat camera colours average to flat colours where valid.
    rgb = cv2.imread(str(out / "rgb.png"))[..., ::-1]
    valid = np.load(out / "valid.npy").repeat(2, axis=0).repeat(2, axis=1)
    assert rgb.shape == (32, 128, 3) and np.all(rgb[~valid] == 0) and rgb[valid].max() > 60
    assert (out / "uncertainty.png").exists()
    rc = main(["predict", "--preset", str(cfg), "--rig", "paper-train", "--images", *files[:2],
               "--out", str(out)])
    assert rc == 1 and "3 cameras but 2 images" in capsys.readouterr().err
    rc = main(["predict", "--preset", "G99", "--rig", "paper-train", "--images", *files,
               "--out", str(out)])
    assert rc == 1 and "unknown model preset" in capsys.readouterr().err
    # Panorama sizes are bounded before any work: by side, then by memory (8 candidates x
    # 160 B a pixel; 1024 x 4096 needs 5 GiB), for the learned model and the baseline alike.
    fresh = tmp_path / "fresh"
    rc = main(["predict", "--preset", str(cfg), "--rig", "paper-train", "--images", *files,
               "--out", str(fresh), "--panorama-size", "100000x400000"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and err[0].endswith(
        "--panorama-size 100000x400000 (rows x columns) has a side beyond the 32768-pixel "
        "bound"), err
    from gijax.io import bounds

    monkeypatch.setattr(bounds, "available_memory", lambda: 8 * 2**30)
    for method in (["--preset", str(cfg)], ["--method", "rtss", "--rtss-preset", "RS-E16"]):
        rc = main(["predict", *method, "--rig", "paper-train", "--images", *files,
                   "--out", str(fresh), "--panorama-size", "1024x4096"])
        err = capsys.readouterr().err
        assert rc == 1 and ("--panorama-size 1024x4096 (rows x columns) needs about "
                            f"{1024 * 4096 * 160 * (8 if '--preset' in method else 16) / 2**30:.1f}"
                            " GiB") in err and "of the 8.0 GiB" in err, err
    assert not fresh.exists()


def test_read_image_gives_rgb_uint8_from_any_file(tmp_path):
    """cv2 writes BGR: the reader returns RGB, drops alpha, repeats grey, scales 16 bits."""
    import cv2

    from gijax.data.images import read_image
    from gijax.io.masks import read_mask

    rgb = np.zeros((2, 3, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 10, 20, 30
    cv2.imwrite(str(tmp_path / "c.png"), rgb[..., ::-1])
    np.testing.assert_array_equal(read_image(tmp_path / "c.png"), rgb)
    bgra = np.concatenate([rgb[..., ::-1], np.full((2, 3, 1), 7, np.uint8)], -1)
    cv2.imwrite(str(tmp_path / "a.png"), bgra)
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), rgb)
    grey = np.array([[0, 5, 255]], np.uint8)
    cv2.imwrite(str(tmp_path / "g.png"), grey)
    np.testing.assert_array_equal(read_image(tmp_path / "g.png"), np.repeat(grey[..., None], 3, -1))
    np.testing.assert_array_equal(read_mask(tmp_path / "g.png"), [[0.0, 1.0, 1.0]])
    wide = np.array([[[0, 257 * 100, 65535]]], np.uint16)          # BGR
    cv2.imwrite(str(tmp_path / "w.png"), wide)
    np.testing.assert_array_equal(read_image(tmp_path / "w.png"), [[[255, 100, 0]]])
    (tmp_path / "bad.png").write_bytes(b"not an image")
    with pytest.raises(ValueError, match="not a readable image"):
        read_image(tmp_path / "bad.png")
    with pytest.raises(FileNotFoundError, match="no such image"):
        read_image(tmp_path / "missing.png")


def test_truncated_jpeg_and_png_are_refused_not_half_decoded(tmp_path):
    """OpenCV decodes a cut JPEG as far as it goes (the rest grey) with only a warning: the
    reader refuses it in one error naming the file; whole files (an Exif thumbnail's scan
    before the image's, bytes a camera appends after the end marker) read as before."""
    import cv2

    from gijax.data.images import read_image

    # Smooth colours, which JPEG keeps within a few levels (noise it would not).
    yy, xx = np.mgrid[0:64, 0:96]
    img = np.stack([xx * 2, yy * 3, 255 - xx - yy], -1).astype(np.uint8)
    jpeg = cv2.imencode(".jpg", img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    whole = tmp_path / "whole.jpg"
    whole.write_bytes(jpeg)
    ref = read_image(whole)
    assert ref.shape == (64, 96, 3) and np.abs(ref.astype(int) - img).mean() < 3
    # Half of the file: OpenCV alone returns a full-size image from it.
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(jpeg[:len(jpeg) // 2])
    assert cv2.imread(str(cut)) is not None
    with pytest.raises(ValueError, match=rf"{cut}: truncated: the image data that starts at "
                                         rf"byte \d+ has no end-of-image marker"):
        read_image(cut)
    # A thumbnail-like complete JPEG inside an APP1 segment before the image, and trailer bytes.
    thumb = cv2.imencode(".jpg", img[:8, :8])[1].tobytes()
    app1 = b"\xff\xe1" + (len(thumb) + 2).to_bytes(2, "big") + thumb
    (tmp_path / "exif.jpg").write_bytes(jpeg[:2] + app1 + jpeg[2:] + b"\x00" * 16)
    np.testing.assert_array_equal(read_image(tmp_path / "exif.jpg"), ref)
    (tmp_path / "exifcut.jpg").write_bytes((jpeg[:2] + app1 + jpeg[2:])[:len(app1) + 400])
    with pytest.raises(ValueError, match="truncated"):
        read_image(tmp_path / "exifcut.jpg")
    png = cv2.imencode(".png", img)[1].tobytes()
    (tmp_path / "cut.png").write_bytes(png[:len(png) - 40])
    with pytest.raises(ValueError, match=r"cut\.png: .*(runs past the end|no PNG end chunk)"):
        read_image(tmp_path / "cut.png")


def test_a_prediction_replaces_only_a_prediction_and_a_stop_leaves_the_old_one(
        setup, tmp_path, monkeypatch):
    """``write_prediction`` writes a new folder or replaces an earlier prediction whole; any
    other folder (a dataset's, one holding an input) is refused naming it, untouched; a stop
    half way (here a full disk while points.ply is written) leaves the earlier prediction as
    it was, with no temporary left behind."""
    import errno
    import json as js

    import gijax.viz.pointcloud
    from gijax.predict import check_prediction_folder

    rig, _, _, out = setup
    data = tmp_path / "dataset"
    data.mkdir()
    (data / "metadata.json").write_text("{}")
    (data / "distance.npy").write_text("mine")
    with pytest.raises(ValueError, match=r"prediction folder .*dataset: exists and is not a "
                                         r"prediction \(it holds metadata.json\)"):
        write_prediction(out, rig, data)
    # Only prediction file names but no record: not gijax's either.
    (data / "metadata.json").unlink()
    with pytest.raises(ValueError, match=r"is not a prediction \(it has no prediction.json\)"):
        write_prediction(out, rig, data)
    assert (data / "distance.npy").read_text() == "mine"
    image = tmp_path / "in" / "cam0.png"
    image.parent.mkdir()
    image.write_bytes(b"x")
    with pytest.raises(ValueError, match="holds the input"):
        check_prediction_folder(image.parent, [image])

    pred = tmp_path / "pred"
    write_prediction(out, rig, pred, title="first")
    before = {p.name: p.read_bytes() for p in pred.iterdir()}
    write_prediction(out, rig, pred, title="second")
    assert js.loads((pred / "prediction.json").read_text())["title"] == "second"

    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    write_prediction(out, rig, pred, title="first")
    monkeypatch.setattr(gijax.viz.pointcloud, "write_ply", disk_full)
    with pytest.raises(OSError, match="No space left"):
        write_prediction(out, rig, pred, title="third")
    assert {p.name: p.read_bytes() for p in pred.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dataset", "in", "pred"]
