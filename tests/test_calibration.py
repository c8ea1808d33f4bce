"""Rig files: gijax YAML round trip, Kalibr and basalt import, and bad-input errors."""

import json

import jax
import numpy as np
import pytest
import yaml

from gijax.geometry.cameras import camera_params, make_camera
from gijax.geometry.occluder import Cylinder
from gijax.geometry.rig import make_rig
from gijax.io.rigfile import load_rig, save_rig

DS_A = [-0.203, 0.589, 232.0, 231.5, 611.5, 513.5]  # Kalibr order: xi alpha fu fv pu pv
EUCM_B = [0.62, 1.1, 240.0, 239.0, 600.0, 500.0]  # alpha beta fu fv pu pv
# cam1 seen from cam0: rotated 90 degrees about z, then moved; T_cn_cnm1 maps cam0 points into
# cam1's frame.
T10 = [[0.0, 1.0, 0.0, 0.05], [-1.0, 0.0, 0.0, -0.3], [0.0, 0.0, 1.0, 0.01], [0, 0, 0, 1]]
T21 = [[1.0, 0.0, 0.0, 0.2], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0, 0, 0, 1]]


def _kalibr(tmp_path, **over):
    chain = {
        "cam0": {"camera_model": "ds", "intrinsics": DS_A, "distortion_model": "none",
                 "distortion_coeffs": [], "resolution": [1224, 1028], "rostopic": "/cam0"},
        "cam1": {"camera_model": "eucm", "intrinsics": EUCM_B, "distortion_model": "none",
                 "distortion_coeffs": [], "resolution": [1224, 1028], "T_cn_cnm1": T10},
        "cam2": {"camera_model": "pinhole", "intrinsics": [300.0, 301.0, 640.0, 480.0],
                 "distortion_model": "equidistant",
                 "distortion_coeffs": [0.01, -0.002, 0.0003, -0.00004],
                 "resolution": [1280, 960], "T_cn_cnm1": T21},
    }
    for cam, fields in over.items():
        for k, v in fields.items():
            if v is None:
                chain[cam].pop(k)
            else:
                chain[cam][k] = v
    p = tmp_path / "camchain.yaml"
    p.write_text(yaml.safe_dump(chain))
    return p


def test_kalibr_import_values_and_chaining(tmp_path):
    rig = load_rig(_kalibr(tmp_path))
    assert rig.names == ("cam0", "cam1", "cam2")
    assert [c.MODEL for c in rig.cameras] == ["ds", "eucm", "kb"]
    p0 = camera_params(rig.cameras[0])
    np.testing.assert_array_equal([p0[k] for k in ("xi", "alpha", "fx", "fy", "cx", "cy")],
                                  np.float32(DS_A))
    p1 = camera_params(rig.cameras[1])
    np.testing.assert_array_equal([p1[k] for k in ("alpha", "beta", "fx", "fy", "cx", "cy")],
                                  np.float32(EUCM_B))
    p2 = camera_params(rig.cameras[2])
    assert (p2["fx"], p2["k4"]) == (300.0, np.float32(-0.00004))
    assert (rig.cameras[2].width, rig.cameras[2].height) == (1280, 960)
    # Camera-to-rig poses with the rig frame = cam0: pose_n = inv(T_n0).
    t10 = np.array(T10)
    t20 = np.array(T21) @ t10
    for i, t in ((0, np.eye(4)), (1, t10), (2, t20)):
        pose = np.linalg.inv(t)
        np.testing.assert_allclose(np.asarray(rig.rotations[i]), pose[:3, :3], atol=1e-7)
        np.testing.assert_allclose(np.asarray(rig.translations[i]), pose[:3, 3], atol=1e-7)
    # cam1's centre in cam0's frame: solve T10 @ [c, 1] = [0, 0, 0, 1] by hand.
    np.testing.assert_allclose(np.asarray(rig.translations[1]), [-0.3, -0.05, -0.01], atol=1e-7)
    # Another camera as the rig frame.
    rig1 = load_rig(_kalibr(tmp_path), frame_camera=1)
    np.testing.assert_allclose(np.asarray(rig1.rotations[1]), np.eye(3), atol=1e-7)
    np.testing.assert_allclose(np.asarray(rig1.translations[0]), t10[:3, 3], atol=1e-7)


def _basalt(tmp_path, mutate=None):
    s = np.sqrt(0.5)
    data = {"value0": {
        "T_imu_cam": [
            {"px": 0.01, "py": 0.02, "pz": 0.0, "qx": 0.0, "qy": 0.0, "qz": 0.0, "qw": 1.0},
            {"px": 0.31, "py": 0.02, "pz": 0.0, "qx": 0.0, "qy": 0.0, "qz": s, "qw": s},
        ],
        "intrinsics": [
            {"camera_type": "ds", "intrinsics": {"fx": 232.0, "fy": 231.0, "cx": 611.5,
                                                 "cy": 513.5, "xi": -0.203, "alpha": 0.589}},
            {"camera_type": "ds", "intrinsics": {"fx": 233.0, "fy": 232.0, "cx": 610.0,
                                                 "cy": 512.0, "xi": -0.2, "alpha": 0.6}},
        ],
        "resolution": [[1224, 1028], [1224, 1028]],
        "calib_accel_bias": [0.0] * 9,
    }}
    if mutate:
        mutate(data["value0"])
    p = tmp_path / "calibration.json"
    p.write_text(json.dumps(data))
    return p


def test_basalt_import_values_and_poses(tmp_path):
    rig = load_rig(_basalt(tmp_path))
    assert [c.MODEL for c in rig.cameras] == ["ds", "ds"]
    p1 = camera_params(rig.cameras[1])
    assert p1 == {k: float(np.float32(v)) for k, v in dict(
        fx=233.0, fy=232.0, cx=610.0, cy=512.0, xi=-0.2, alpha=0.6).items()}
    # cam1 relative to cam0: rotated 90 degrees about z, 0.3 m along x.
    np.testing.assert_allclose(np.asarray(rig.rotations[1]), [[0, -1, 0], [1, 0, 0], [0, 0, 1]],
                               atol=1e-7)
    np.testing.assert_allclose(np.asarray(rig.translations[1]), [0.3, 0.0, 0.0], atol=1e-7)
    np.testing.assert_allclose(np.asarray(rig.translations[0]), 0.0, atol=0)
    # The panorama is centred between the cameras, not on camera 0.
    np.testing.assert_allclose(np.asarray(rig.reference), [0.15, 0.0, 0.0], atol=1e-7)


def test_gijax_yaml_round_trip_of_a_unified_camera(tmp_path):
    cam = make_camera("omni", dict(fx=500.0, fy=501.5, cx=641.0, cy=510.2, xi=1.2, k1=-0.25,
                                   k2=0.06, p1=-1e-4, p2=5e-4), 1280, 1024, 200.0)
    rig = make_rig([cam], [np.eye(3)], [[0.0, 0.0, 0.0]])
    path = save_rig(rig, tmp_path / "rig.yaml")
    entry = yaml.safe_load(path.read_text())["cameras"][0]
    assert entry["model"] == "omni" and entry["intrinsics"]["p2"] == 5e-4
    back = load_rig(path)
    assert type(back.cameras[0]) is type(cam)
    for a, b in zip(jax.tree_util.tree_leaves(rig), jax.tree_util.tree_leaves(back)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_gijax_yaml_round_trip(tmp_path):
    cams = [make_camera("ds", dict(fx=232.0, fy=231.0, cx=611.5, cy=513.5, xi=-0.203,
                                   alpha=0.589), 1224, 1028, 190.0),
            make_camera("kb", dict(fx=300.0, fy=301.0, cx=63.5, cy=47.5, k1=0.01, k2=-0.002,
                                   k3=0.0003, k4=-4e-5), 128, 96, 185.0)]
    c, s = np.cos(0.3), np.sin(0.3)
    rots = [np.eye(3), [[c, -s, 0], [s, c, 0], [0, 0, 1]]]
    mask = np.ones((96, 128), np.float32)
    mask[:10, :20] = 0
    rig = make_rig(cams, rots, [[0, 0, 0], [0.3, 0.1, -0.01]], reference=[0.1, 0.2, 0.0],
                   masks=[None, mask], occluder=Cylinder(*np.float32([0.1, 0.0, 0.05, 0.0, 0.1])),
                   names=["left", "right"])
    path = save_rig(rig, tmp_path / "sub" / "rig.yaml")
    back = load_rig(path)
    assert back.names == rig.names and back.masks[0] is None
    assert jax.tree_util.tree_structure(back) == jax.tree_util.tree_structure(rig)
    for a, b in zip(jax.tree_util.tree_leaves(rig), jax.tree_util.tree_leaves(back)):
        assert np.asarray(a).dtype == np.asarray(b).dtype
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # No temporary files are left behind.
    assert sorted(p.name for p in path.parent.iterdir()) == ["rig.yaml", "rig_right_mask.png"]
    # The quaternion form reads to the same rotation.
    data = yaml.safe_load(path.read_text())
    data["cameras"][1].pop("rotation")
    data["cameras"][1]["quaternion"] = [0.0, 0.0, float(np.sin(0.15)), float(np.cos(0.15))]
    (tmp_path / "sub" / "q.yaml").write_text(yaml.safe_dump(data))
    q = load_rig(tmp_path / "sub" / "q.yaml")
    np.testing.assert_allclose(np.asarray(q.rotations[1]), np.asarray(rig.rotations[1]),
                               atol=1e-7)


def test_builtin_names_load():
    rig = load_rig("paper-test3")
    assert rig.num_cameras == 4
    with pytest.raises(FileNotFoundError, match="paper-train"):
        load_rig("no-such-rig")


def _gijax_file(tmp_path, mutate):
    data = {"gijax_rig": 1, "reference": [0, 0, 0], "cameras": [
        {"name": "a", "model": "ds", "intrinsics": dict(fx=232.0, fy=231.0, cx=611.5, cy=513.5,
                                                         xi=-0.2, alpha=0.6),
         "resolution": [1224, 1028], "rotation": np.eye(3).tolist(), "translation": [0, 0, 0]},
    ]}
    mutate(data)
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _cam(data):
    return data["cameras"][0]


BAD_GIJAX = {
    "missing field": (lambda d: _cam(d).pop("translation"), "translation"),
    "unknown field": (lambda d: _cam(d).update(colour="red"), "colour"),
    "unknown model": (lambda d: _cam(d).update(model="fisheye624"), "model"),
    "wrong intrinsics": (lambda d: _cam(d)["intrinsics"].pop("xi"), "intrinsics"),
    "nan": (lambda d: _cam(d)["intrinsics"].update(fx=float("nan")), "intrinsics.fx"),
    "inf": (lambda d: _cam(d).update(translation=[0, float("inf"), 0]), "translation"),
    "not orthonormal": (lambda d: _cam(d).update(rotation=[[1, 0.1, 0], [0, 1, 0], [0, 0, 1]]),
                        "rotation"),
    "reflection": (lambda d: _cam(d).update(rotation=[[-1, 0, 0], [0, 1, 0], [0, 0, 1]]),
                   "rotation"),
    "zero cameras": (lambda d: d.update(cameras=[]), "cameras"),
    "bad resolution": (lambda d: _cam(d).update(resolution=[1224]), "resolution"),
    "bad quaternion": (lambda d: (_cam(d).pop("rotation"),
                                  _cam(d).update(quaternion=[0, 0, 0.5, 0.5])), "quaternion"),
}


@pytest.mark.parametrize("case", sorted(BAD_GIJAX))
def test_bad_gijax_file(tmp_path, case):
    mutate, field = BAD_GIJAX[case]
    path = _gijax_file(tmp_path, mutate)
    with pytest.raises(ValueError) as exc:
        load_rig(path)
    msg = str(exc.value)
    assert str(path) in msg and f"'{field}'" in msg and " must be " in msg and "; found " in msg
    if case != "zero cameras":
        assert "camera 'a'" in msg


BAD_KALIBR = {
    "unknown model": ({"cam1": {"camera_model": "scaramuzza"}}, "cam1", "camera_model"),
    "omni intrinsics": ({"cam1": {"camera_model": "omni"}}, "cam1", "intrinsics"),
    "wrong count": ({"cam0": {"intrinsics": DS_A[:5]}}, "cam0", "intrinsics"),
    "nan": ({"cam2": {"distortion_coeffs": [0.0, float("nan"), 0.0, 0.0]}}, "cam2",
            "distortion_coeffs"),
    "missing chain": ({"cam1": {"T_cn_cnm1": None}}, "cam1", "T_cn_cnm1"),
    "not orthonormal": ({"cam2": {"T_cn_cnm1": [[1, 0, 0, 0], [0, 2, 0, 0], [0, 0, 1, 0],
                                                [0, 0, 0, 1]]}}, "cam2", "T_cn_cnm1"),
    "radtan": ({"cam2": {"distortion_model": "radtan"}}, "cam2", "distortion_model"),
    "missing resolution": ({"cam0": {"resolution": None}}, "cam0", "resolution"),
}


@pytest.mark.parametrize("case", sorted(BAD_KALIBR))
def test_bad_kalibr_file(tmp_path, case):
    over, cam, field = BAD_KALIBR[case]
    path = _kalibr(tmp_path, **over)
    with pytest.raises(ValueError) as exc:
        load_rig(path)
    msg = str(exc.value)
    assert str(path) in msg and f"camera '{cam}'" in msg and f"'{field}'" in msg


BAD_BASALT = {
    "unknown model": (lambda v: v["intrinsics"][1].update(camera_type="pinhole"), "cam1",
                      "camera_type"),
    "wrong intrinsics": (lambda v: v["intrinsics"][0]["intrinsics"].pop("alpha"), "cam0",
                         "intrinsics"),
    "bad quaternion": (lambda v: v["T_imu_cam"][1].update(qw=2.0), "cam1", "T_imu_cam"),
    "inf": (lambda v: v["T_imu_cam"][0].update(px=float("inf")), "cam0", "T_imu_cam.px"),
    "zero cameras": (lambda v: v.update(T_imu_cam=[], intrinsics=[], resolution=[]), None,
                     "value0.T_imu_cam"),
    "count mismatch": (lambda v: v["resolution"].pop(), None, "value0.T_imu_cam"),
}


@pytest.mark.parametrize("case", sorted(BAD_BASALT))
def test_bad_basalt_file(tmp_path, case):
    mutate, cam, field = BAD_BASALT[case]
    path = _basalt(tmp_path, mutate)
    with pytest.raises(ValueError) as exc:
        load_rig(path)
    msg = str(exc.value)
    assert str(path) in msg and f"'{field}'" in msg
    if cam:
        assert f"camera '{cam}'" in msg


def test_unrecognised_and_missing_files(tmp_path):
    p = tmp_path / "x.yaml"
    p.write_text("foo: 1\n")
    with pytest.raises(ValueError, match="x.yaml"):
        load_rig(p)
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        load_rig(tmp_path / "nope.yaml")


def test_cli_rig_show_and_plot(tmp_path, capsys):
    from gijax.cli import main

    path = _kalibr(tmp_path)
    png = tmp_path / "rig.png"
    assert main(["rig", "show", str(path), "--plot", str(png), "--save",
                 str(tmp_path / "out.yaml")]) == 0
    out = capsys.readouterr().out
    assert "cam2: model kb, 1280x960 px" in out and "0.3000" in out  # cam0-cam1 baseline
    # Each lens's own limit instead of the 360 degrees a calibration's open cone would show:
    # Double Sphere 2 arccos(-w2) with xi = -0.203, alpha = 0.589 (w2 = 0.5684) is 249.3.
    assert "fov 360.0" not in out and "lens model limit 249.3 deg" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert load_rig(tmp_path / "out.yaml").cameras[1].MODEL == "eucm"
    assert main(["rig", "show", str(tmp_path / "missing.yaml")]) == 1
