"""The one mask reader: nonzero = valid whatever the bit depth or channels, the same mask from
a rig file, a dataset and ``--masks``, and one clear line for a missing, unreadable or
wrong-sized file."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gijax.io.masks import read_mask

# 1 = valid; the 16-bit file's valid values are all below 256, which an 8-bit read turns to 0.
VALID = np.array([[0, 1, 1, 0, 1], [1, 0, 0, 1, 1]], np.float32)


def _write_masks(folder) -> dict:
    files = {"1-bit": folder / "bilevel.png", "8-bit": folder / "grey8.png",
             "16-bit": folder / "grey16.png", "colour": folder / "colour.png"}
    cv2.imwrite(str(files["1-bit"]), (VALID * 255).astype(np.uint8),
                [cv2.IMWRITE_PNG_BILEVEL, 1])
    cv2.imwrite(str(files["8-bit"]), (VALID * 3).astype(np.uint8))
    cv2.imwrite(str(files["16-bit"]), (VALID * np.array([[1, 2, 255, 7, 128]] * 2)).astype(
        np.uint16))
    colour = np.zeros((2, 5, 4), np.uint8)
    colour[..., 3] = 255                              # alpha is ignored
    colour[..., 1] = (VALID * 9).astype(np.uint8)     # only green set where valid
    cv2.imwrite(str(files["colour"]), colour)
    return files


def test_every_bit_depth_reads_the_same_mask(tmp_path):
    files = _write_masks(tmp_path)
    with open(files["1-bit"], "rb") as f:             # a 1-bit PNG: IHDR bit depth 1
        assert f.read(25)[24] == 1
    assert cv2.imread(str(files["16-bit"]), cv2.IMREAD_UNCHANGED).dtype == np.uint16
    for kind, path in files.items():
        mask = read_mask(path, (2, 5))
        assert mask.dtype == np.float32, kind
        np.testing.assert_array_equal(mask, VALID, err_msg=kind)


def test_rig_file_dataset_and_predict_masks_agree(tmp_path):
    """The 16-bit mask is the same mask in a rig file and on ``predict --masks`` (whose reader
    once scaled it to 8 bits and so to empty)."""
    from gijax.geometry.cameras import make_camera
    from gijax.geometry.rig import make_rig
    from gijax.io.rigfile import load_rig, save_rig

    path = _write_masks(tmp_path)["16-bit"]
    cam = make_camera("equidistant", dict(fx=2.0, fy=2.0, cx=2.0, cy=0.5), 5, 2, 180.0)
    rig_path = save_rig(make_rig([cam], np.eye(3)[None], [[0.0, 0.0, 0.0]]), tmp_path / "r.yaml")
    rig_path.write_text(rig_path.read_text().rstrip("\n") + f"\n  mask: {path.name}\n")
    np.testing.assert_array_equal(np.asarray(load_rig(rig_path).masks[0]), VALID)
    np.testing.assert_array_equal(read_mask(path), VALID)         # predict --masks: no size


def test_missing_unreadable_and_wrong_size_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"^--masks: camera 'c0': missing file .*none\.png"):
        read_mask(tmp_path / "none.png", (2, 5), "--masks: camera 'c0'")
    (tmp_path / "text.png").write_text("not an image")
    with pytest.raises(ValueError, match=r"text\.png is not a readable image"):
        read_mask(tmp_path / "text.png")
    good = _write_masks(tmp_path)["8-bit"]
    (tmp_path / "cut.png").write_bytes(good.read_bytes()[:-20])
    with pytest.raises(ValueError, match=r"cut\.png is truncated"):
        read_mask(tmp_path / "cut.png")
    with pytest.raises(ValueError, match=r"grey8\.png is 5x2 px but the camera's image is 4x2 px"):
        read_mask(good, (2, 4))


def test_a_truncated_jpeg_mask_is_refused(tmp_path):
    import cv2

    mask = np.zeros((40, 60), np.uint8)
    mask[10:30, 15:45] = 255
    data = cv2.imencode(".jpg", mask)[1].tobytes()
    (tmp_path / "m.jpg").write_bytes(data)
    np.testing.assert_array_equal(read_mask(tmp_path / "m.jpg") > 0, cv2.imdecode(
        np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) > 0)
    (tmp_path / "cut.jpg").write_bytes(data[:len(data) * 2 // 3])
    with pytest.raises(ValueError, match=r"--masks camera 0: .*cut\.jpg: truncated"):
        read_mask(tmp_path / "cut.jpg", label="--masks camera 0")
