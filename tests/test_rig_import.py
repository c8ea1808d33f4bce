"""Calibration import with per-camera masks, and the warning for rigs used without masks."""

import json
import warnings

import cv2
import numpy as np
import pytest
import yaml

from gijax.cli import main
from gijax.io.masks import UnmaskedRigWarning, attach_masks, import_rig, warn_if_unmasked
from gijax.io.rigfile import load_rig

W, H = 64, 48  # small images keep the PNGs and the report cheap
# Four cameras on a 0.3 m square, looking along +z, each rotated a quarter turn further.
CENTRES = [(0.0, 0.0), (0.3, 0.0), (0.3, 0.3), (0.0, 0.3)]


def _basalt(tmp_path, sizes=None):
    s = np.sqrt(0.5)
    quats = [(0.0, 0.0, 0.0, 1.0), (0.0, 0.0, s, s), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, s, -s)]
    sizes = sizes or [[W, H]] * 4
    data = {"value0": {
        "T_imu_cam": [{"px": x, "py": y, "pz": 0.0, "qx": q[0], "qy": q[1], "qz": q[2],
                       "qw": q[3]} for (x, y), q in zip(CENTRES, quats)],
        "intrinsics": [{"camera_type": "ds", "intrinsics": {
            "fx": 12.0, "fy": 12.0, "cx": w / 2 - 0.5, "cy": h / 2 - 0.5, "xi": -0.2,
            "alpha": 0.6}} for w, h in sizes],
        "resolution": sizes,
    }}
    p = tmp_path / "calibration.json"
    p.write_text(json.dumps(data))
    return p


def _mask_pngs(tmp_path, sizes=None, value=255):
    """One PNG per camera: camera i's mask has a block of i + 1 rows blanked at the top."""
    paths, arrays = [], []
    for i, (w, h) in enumerate(sizes or [(W, H)] * 4):
        m = np.full((h, w), value, np.uint8)
        m[:i + 1] = 0
        p = tmp_path / f"m{i}.png"
        assert cv2.imwrite(str(p), m)
        paths.append(p)
        arrays.append((m > 0).astype(np.float32))
    return paths, arrays


def test_import_with_masks_round_trip(tmp_path):
    calib = _basalt(tmp_path)
    paths, expected = _mask_pngs(tmp_path, value=1)  # nonzero is valid, not only 255
    rig = import_rig(calib, masks=paths, names=["n0", "n1", "n2", "n3"])
    plain = load_rig(calib)
    np.testing.assert_array_equal(np.asarray(rig.translations), np.asarray(plain.translations))
    for got, want in zip(rig.masks, expected):
        np.testing.assert_array_equal(np.asarray(got), want)
    out = tmp_path / "out" / "rig.yaml"
    assert main(["rig", "import", str(calib), "--masks", *map(str, paths), "--names", "n0",
                 "n1", "n2", "n3", "--out", str(out)]) == 0
    doc = yaml.safe_load(out.read_text())
    assert [c["mask"] for c in doc["cameras"]] == [f"rig_n{i}_mask.png" for i in range(4)]
    back = load_rig(out)
    assert back.names == ("n0", "n1", "n2", "n3")
    for got, want in zip(back.masks, expected):
        np.testing.assert_array_equal(np.asarray(got), want)
    np.testing.assert_allclose(np.asarray(back.translations)[:, :2], CENTRES, atol=1e-7)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnmaskedRigWarning)
        assert warn_if_unmasked(back, str(out)) == ()


def test_import_summary(tmp_path, capsys):
    calib = _basalt(tmp_path)
    paths, _ = _mask_pngs(tmp_path)
    out = tmp_path / "rig.yaml"
    assert main(["rig", "import", str(calib), "--masks", *map(str, paths), "--out",
                 str(out)]) == 0
    text = capsys.readouterr().out
    assert f"imported {calib}" in text and f"wrote {out}" in text
    assert text.count(f"model ds, {W}x{H} px") == 4
    assert "0.3000" in text and "0.4243" in text  # side and diagonal of the square
    # Camera 3 has 4 of 48 rows blanked: 91.7 % valid.
    assert "mask 91.7% valid" in text
    assert f"cam3: {paths[3]} -> {tmp_path / 'rig_cam3_mask.png'}" in text
    assert "no mask" not in text


def test_import_without_masks_says_so(tmp_path, capsys):
    calib = _basalt(tmp_path)
    assert main(["rig", "import", str(calib), "--out", str(tmp_path / "rig.yaml")]) == 0
    text = capsys.readouterr().out
    assert "cameras cam0, cam1, cam2, cam3 have no mask" in text and "--masks" in text


def test_mask_count_mismatch(tmp_path, capsys):
    calib = _basalt(tmp_path)
    paths, _ = _mask_pngs(tmp_path)
    with pytest.raises(ValueError) as exc:
        import_rig(calib, masks=paths[:3])
    msg = str(exc.value)
    assert "3 mask file(s)" in msg and "4 cameras" in msg and str(calib) in msg
    assert "cam0, cam1, cam2, cam3" in msg
    out = tmp_path / "rig.yaml"
    assert main(["rig", "import", str(calib), "--masks", *map(str, paths[:3]), "--out",
                 str(out)]) == 1
    assert "3 mask file(s)" in capsys.readouterr().err
    assert not out.exists()


def test_mask_size_mismatch(tmp_path):
    sizes = [[W, H], [W, H], [80, 60], [W, H]]
    calib = _basalt(tmp_path, sizes)
    paths, _ = _mask_pngs(tmp_path)  # all W x H: camera 2's is the wrong size
    with pytest.raises(ValueError) as exc:
        import_rig(calib, masks=paths)
    msg = str(exc.value)
    assert str(paths[2]) in msg and "'cam2'" in msg
    assert f"is {W}x{H} px" in msg and "image is 80x60 px" in msg
    with pytest.raises(FileNotFoundError, match="cam1"):
        import_rig(calib, masks=[paths[0], tmp_path / "none.png", *paths[2:]])


def test_rig_file_mask_of_wrong_size_names_rig_and_mask(tmp_path):
    calib = _basalt(tmp_path)
    paths, _ = _mask_pngs(tmp_path)
    out = tmp_path / "rig.yaml"
    assert main(["rig", "import", str(calib), "--masks", *map(str, paths), "--out",
                 str(out)]) == 0
    cv2.imwrite(str(tmp_path / "rig_cam1_mask.png"), np.zeros((H + 1, W), np.uint8))
    with pytest.raises(ValueError) as exc:
        load_rig(out)
    msg = str(exc.value)
    assert str(out) in msg and "'cam1'" in msg and "'mask'" in msg
    assert f"is {W}x{H + 1} px" in msg and f"image is {W}x{H} px" in msg


def test_names_checked(tmp_path):
    calib = _basalt(tmp_path)
    with pytest.raises(ValueError, match="2 name"):
        import_rig(calib, names=["a", "b"])
    with pytest.raises(ValueError, match="distinct"):
        import_rig(calib, names=["a", "a", "b", "c"])
    with pytest.raises(ValueError, match="letters"):
        import_rig(calib, names=["a", "b/c", "d", "e"])


def test_show_save_with_masks(tmp_path, capsys):
    calib = _basalt(tmp_path)
    paths, expected = _mask_pngs(tmp_path)
    out = tmp_path / "shown.yaml"
    assert main(["rig", "show", str(calib), "--masks", *map(str, paths), "--save",
                 str(out)]) == 0
    assert "no mask" not in capsys.readouterr().out
    for got, want in zip(load_rig(out).masks, expected):
        np.testing.assert_array_equal(np.asarray(got), want)


def test_unmasked_warning(tmp_path):
    calib = _basalt(tmp_path)
    rig = load_rig(calib)
    with pytest.warns(UnmaskedRigWarning) as rec:
        assert warn_if_unmasked(rig, str(calib)) == ("cam0", "cam1", "cam2", "cam3")
    msg = str(rec[0].message)
    assert msg.startswith(f"{calib}: cameras cam0, cam1, cam2, cam3 have no mask")
    assert "matched as scene" in msg and "gijax rig import" in msg and "--masks" in msg
    paths, _ = _mask_pngs(tmp_path)
    partial = attach_masks(rig, paths, "calib").replace(
        masks=(None,) + attach_masks(rig, paths, "calib").masks[1:])
    with pytest.warns(UnmaskedRigWarning, match="camera cam0 has no mask"):
        assert warn_if_unmasked(partial, "rig.yaml") == ("cam0",)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnmaskedRigWarning)
        # Masks given with the images replace the rig's; built-in layouts are rendered rigs
        # whose body is masked by construction (and are not checked).
        assert warn_if_unmasked(rig, str(calib), other_masks=True) == ()
        builtin = load_rig("paper-train")
        assert warn_if_unmasked(builtin.replace(masks=(None,) * 3), "paper-train") == ()


def test_a_warning_on_the_command_line_is_one_line_without_its_source(tmp_path, monkeypatch,
                                                                     capsys):
    import gijax.cli.cmd_rig as cmd_rig

    calib = _basalt(tmp_path)

    def show(args):
        warn_if_unmasked(load_rig(args.rig), args.rig)
        return 0

    monkeypatch.setattr(cmd_rig, "_show", show)
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        assert main(["rig", "show", str(calib)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"gijax rig: warning: {calib}: cameras cam0, cam1, cam2, cam3 "
                             "have no mask")
    assert "masks.py" not in err[0] and "UnmaskedRigWarning" not in err[0]


def test_a_camera_beyond_the_size_bounds_is_refused_before_anything_is_allocated(tmp_path,
                                                                                  monkeypatch):
    import yaml

    from gijax.io import bounds
    from gijax.io.rigfile import save_rig

    path = save_rig(load_rig("paper-train"), tmp_path / "rig.yaml")
    doc = yaml.safe_load(path.read_text())
    camera = doc["cameras"][0]
    camera["resolution"] = [10**6, 10**6]
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ValueError, match=r"field 'resolution'.*32768-pixel bound"):
        load_rig(path)
    # A size within the side bound but beyond memory: half of what is available decides.
    camera["resolution"] = [4096, 4096]
    path.write_text(yaml.safe_dump(doc))
    monkeypatch.setattr(bounds, "available_memory", lambda: 64 * 2**20)
    with pytest.raises(ValueError, match=r"needs about 0\.2 GiB, more than half of the 0\.1 GiB"):
        load_rig(path)
