"""Reading a dataset tree in the paper's released layout.

The tree is written here with plain json / csv / OpenCV, following the release's dataset code
(manifest camera models and samplers, metadata cams, frame graph, masks.json,
data_partitions.json, per-trajectory meta.json and CSV), not with gijax's writer. Expected
values come from closed forms written out in the tests.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from gijax.data.release import ReleaseDatasetReader, detect_layout
from gijax.geometry import cameras as cam_lib
from gijax.geometry.panorama import Panorama

SIZE = 24          # input fisheye images
RIG_SIZE = 32      # the rig's distance image
PANO = Panorama.hemisphere(8, 32)
FOV = 195.0
DS = {"type": "DoubleSphere", "xi": -0.2, "alpha": 0.59, "fx": 10.0, "fy": 10.5, "cx": 12.0,
      "cy": 11.5, "fov_degree": FOV, "shape_struct": {"H": SIZE, "W": SIZE}}
LIN = {"type": "LinearSphere", "fov_degree": FOV, "shape_struct": {"H": SIZE, "W": SIZE},
       "in_to_tensor": True, "out_to_numpy": False}
LIN_RIG = {"type": "LinearSphere", "fov_degree": FOV,
           "shape_struct": {"H": RIG_SIZE, "W": RIG_SIZE}}
CAM_POS = [(0.15, 0.0, 0.0), (-0.05, 0.2, 0.0), (-0.1, -0.12, 0.01)]
YAW1 = math.radians(30.0)  # camera 1 turned about its optical axis


def identity_rm():
    return {"type": "rotation_matrix", "data": [1, 0, 0, 0, 1, 0, 0, 0, 1]}


def write_png_float(path: Path, d: np.ndarray) -> None:
    """The release's write_compressed_float: float32 bytes as 4 uint8 channels."""
    d = np.ascontiguousarray(d.astype("<f4")[..., None])
    assert cv2.imwrite(str(path), d.view("<u1"))


def build_tree(root: Path, rig_distance=None, n_frames: int = 2) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    manifest = {
        "camera_models": {"fish_lin": LIN, "fish_ds": DS, "rig_fish": LIN_RIG},
        "samplers": [
            {"description": f"cam{k} fisheye RGB sampler", "table_header": f"cam{k}_rgb_fisheye",
             "raw_camera": f"cam{k}", "mvs_main_cam_model_for_cam": True, "mvs_cam_key": f"cam{k}",
             "sampler": {"type": "FullViewRotation",
                         "cam_model_key": "fish_ds" if k == 2 else "fish_lin"}}
            for k in range(3)] + [
            {"description": "rig fisheye distance sampler", "mvs_main_cam_model_for_cam": True,
             "mvs_cam_key": "rig", "sampler": {"cam_model_key": "rig_fish"}},
            {"description": "not the main model", "mvs_main_cam_model_for_cam": False,
             "mvs_cam_key": "cam0", "sampler": {"cam_model_key": "rig_fish"}}],
    }
    (root / "manifest.json").write_text(json.dumps(manifest))
    meta = {"cams": [{"frame": f"cbf{k}", "image_frame": f"cif{k}", "is_rig": k == 0,
                      "img_types": ["CubeScene"], "airsim_cam_nums": [k]} for k in range(3)],
            "rig_img_types": ["CubeDistance"]}
    (root / "metadata.json").write_text(json.dumps(meta))
    # rifs: the label panorama frame; its -y axis is the rig camera's optical axis (+z of rif).
    rifs = {"type": "rotation_matrix", "data": [1, 0, 0, 0, 0, 1, 0, -1, 0]}
    c, s = math.cos(YAW1 / 2), math.sin(YAW1 / 2)
    transforms = [
        {"f0": "rbf", "f1": "rif", "pose": {"type": "reference", "key": "same"}},
        {"f0": "rif", "f1": "rifs", "pose": {"type": "create", "position": [0, 0, 0],
                                             "orientation": rifs}},
        {"f0": "rbf", "f1": "cif0", "pose": {"type": "create", "position": list(CAM_POS[0]),
                                             "orientation": identity_rm()}},
        {"f0": "rif", "f1": "cif1", "pose": {"type": "create", "position": list(CAM_POS[1]),
                                             "orientation": {"type": "quaternion", "data": {
                                                 "x": 0.0, "y": 0.0, "z": s, "w": c}}}},
        {"f0": "cif0", "f1": "cif2", "pose": {"type": "create", "position": list(
            np.subtract(CAM_POS[2], CAM_POS[0])), "orientation": identity_rm()}},
    ]
    graph = {"frames": [{"name": n, "comment": n} for n in
                        ("rbf", "rif", "rifs", "cif0", "cif1", "cif2")],
             "typical_poses": {"same": {"position": [0, 0, 0], "orientation": identity_rm()}},
             "transforms": transforms}
    (root / "frame_graph.json").write_text(json.dumps(graph))

    valid = np.full((SIZE, SIZE), 255, np.uint8)
    valid[:3, :] = 0
    valid[5, 5] = 254   # only exactly 255 is valid in the release
    for k in range(3):
        assert cv2.imwrite(str(root / f"valid_mask_{k}.png"), valid)
    aug = np.full((SIZE, SIZE), 255, np.uint8)
    aug[:, :6] = 0
    assert cv2.imwrite(str(root / "aug_mask_1.png"), aug)
    (root / "masks.json").write_text(json.dumps({
        "masks": [{"raw_camera": f"cam{k}", "mask": f"valid_mask_{k}.png"} for k in range(3)],
        "masks_augmented": [{"raw_camera": "cam1", "mask": "aug_mask_1.png"}]}))

    (root / "data_partitions.json").write_text(json.dumps({
        "train": {"EnvA": ["P000"]}, "validate": {"EnvA": ["P001"]}}))
    if rig_distance is None:
        rig_distance = np.full((RIG_SIZE, RIG_SIZE), 7.25, np.float32)
    for traj in ("P000", "P001"):
        tdir = root / "EnvA" / traj
        for sub in ("cam0", "cam1", "cam2", "rig"):
            (tdir / sub).mkdir(parents=True, exist_ok=True)
        (tdir / "meta.json").write_text(json.dumps({"selected_file_list": "selected.csv"}))
        header = ["cam0_rgb_fisheye", "cam1_rgb_fisheye", "cam2_rgb_fisheye", "rig_rgb_fisheye",
                  "rig_dist_fisheye"]
        with open(tdir / "selected.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(header)
            for i in range(n_frames):
                row = []
                for k in range(3):
                    bgr = np.full((SIZE, SIZE, 3), 100 + i, np.uint8)
                    bgr[7, 5] = (10, 20, 30)  # B, G, R as OpenCV stores them
                    cv2.imwrite(str(tdir / f"cam{k}" / f"{i:06d}_CubeScene.png"), bgr)
                    row.append(f"cam{k}\\{i:06d}_CubeScene.png")  # Windows separators
                cv2.imwrite(str(tdir / "rig" / f"{i:06d}_CubeScene.png"),
                            np.zeros((RIG_SIZE, RIG_SIZE, 3), np.uint8))
                write_png_float(tdir / "rig" / f"{i:06d}_CubeDistance.png", rig_distance)
                row += [f"rig/{i:06d}_CubeScene.png", f"rig/{i:06d}_CubeDistance.png"]
                w.writerow(row)
    return root


@pytest.fixture()
def tree(tmp_path):
    return build_tree(tmp_path / "release")


def g_dir(row: int, col: int, pano: Panorama = PANO) -> np.ndarray:
    """gijax panorama pixel centre direction, written out from docs/geometry conventions."""
    lon = -math.pi + (col + 0.5) * 2 * math.pi / pano.width
    theta = pano.lat_min + (row + 0.5) * (pano.lat_max - pano.lat_min) / pano.height + math.pi / 2
    # Longitude grows towards -y: the common layout, column grows to the right.
    return np.array([math.sin(theta) * math.cos(lon), -math.sin(theta) * math.sin(lon),
                     math.cos(theta)])


def lin_pixel(p: np.ndarray, w: int) -> tuple[float, float]:
    """LinearSphere: r = angle * W / fov, centre W/2 (release pixel coordinates)."""
    ang = math.acos(p[2] / np.linalg.norm(p))
    phi = math.atan2(p[1], p[0])
    r = ang * w / math.radians(FOV)
    return r * math.cos(phi) + w / 2, r * math.sin(phi) + w / 2


def test_detects_layouts(tree, tmp_path):
    assert detect_layout(tree) == "release"
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(FileNotFoundError, match="missing manifest.json"):
        detect_layout(empty)
    (empty / "manifest.json").write_text(json.dumps({"name": "x"}))
    with pytest.raises(ValueError, match="neither a gijax manifest.*'camera_models'"):
        detect_layout(empty)


def test_rig_poses_in_gijax_frame(tree):
    r = ReleaseDatasetReader(tree, pano=PANO)
    # Frame G from rifs: x_G = z_rifs = y_rif, y_G = -x_rifs = -x_rif, z_G = -y_rifs = z_rif.
    for k, (x, y, z) in enumerate(CAM_POS):
        np.testing.assert_allclose(np.asarray(r.rig.translations[k]), [y, -x, z], atol=1e-7)
    m = np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1]], float)
    c, s = math.cos(YAW1), math.sin(YAW1)
    np.testing.assert_allclose(np.asarray(r.rig.rotations[0]), m, atol=1e-7)
    np.testing.assert_allclose(np.asarray(r.rig.rotations[1]),
                               m @ [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-6)
    np.testing.assert_allclose(np.asarray(r.rig.reference), 0.0)
    assert r.rig.names == ("cam0", "cam1", "cam2") and len(r) == 2


def test_camera_models_project_like_manifest(tree):
    r = ReleaseDatasetReader(tree, pano=PANO)
    p = np.array([0.3, -0.2, 1.0])
    # Double Sphere closed form with the manifest's parameters (release pixel coordinates).
    xi, a = DS["xi"], DS["alpha"]
    d1 = np.linalg.norm(p)
    d2 = math.sqrt(p[0] ** 2 + p[1] ** 2 + (xi * d1 + p[2]) ** 2)
    den = a * d2 + (1 - a) * (xi * d1 + p[2])
    u_rel, v_rel = DS["fx"] * p[0] / den + DS["cx"], DS["fy"] * p[1] / den + DS["cy"]
    px, ok = cam_lib.project(r.rig.cameras[2], p)
    assert bool(ok)
    # gijax's pixel centres are 0.5 px before the release's.
    np.testing.assert_allclose(np.asarray(px), [u_rel - 0.5, v_rel - 0.5], atol=1e-4)
    # LinearSphere: equidistant with f = W / fov.
    q = np.array([-0.7, 0.4, 0.2])
    u_rel, v_rel = lin_pixel(q, SIZE)
    px, ok = cam_lib.project(r.rig.cameras[0], q)
    assert bool(ok)
    np.testing.assert_allclose(np.asarray(px), [u_rel - 0.5, v_rel - 0.5], atol=1e-4)
    assert r.rig.cameras[0].MODEL == "equidistant" and r.rig.cameras[2].MODEL == "ds"
    np.testing.assert_allclose(float(r.rig.cameras[0].fov), math.radians(FOV), rtol=1e-6)


def test_images_masks_and_constant_label(tree):
    r = ReleaseDatasetReader(tree, pano=PANO)
    s = r[1]
    assert s["images"].shape == (3, SIZE, SIZE, 3) and s["images"].dtype == np.uint8
    assert tuple(s["images"][0, 7, 5]) == (30, 20, 10)       # BGR on disk -> RGB
    assert tuple(s["images"][0, 0, 0]) == (101, 101, 101)    # frame 1
    # masks_augmented zeroes camera 1's image outside that mask; its mask stays masks.json's.
    assert np.all(s["images"][1][:, :6] == 0) and np.all(s["images"][1][:, 6:] > 0)
    assert s["masks"].shape == (3, SIZE, SIZE)
    assert s["masks"][0, 0, 0] == 0 and s["masks"][0, 5, 5] == 0 and s["masks"][0, 5, 6] == 1
    assert int(s["masks"][1].sum()) == SIZE * SIZE - 3 * SIZE - 1
    # A constant distance through the float32-in-PNG encoding and the resampling.
    assert s["pano_distance"].shape == PANO.shape and s["pano_distance"].dtype == np.float32
    np.testing.assert_array_equal(s["pano_distance"], np.float32(7.25))
    assert (s["trajectory"], s["frame"], s["index"]) == ("EnvA/P000", 1, 1)


def test_label_orientation_matches_closed_form(tmp_path):
    # A ramp in the rig image's column: bilinear resampling reproduces it exactly, so each
    # label pixel is 2 + 0.1 * (u - 0.5) at the column u where its ray meets the rig image.
    cols = np.arange(RIG_SIZE, dtype=np.float32)
    ramp = np.tile(2.0 + 0.1 * cols, (RIG_SIZE, 1)).astype(np.float32)
    root = build_tree(tmp_path / "ramp", rig_distance=ramp, n_frames=1)
    label = ReleaseDatasetReader(root, pano=PANO)[0]["pano_distance"]
    checked = 0
    for row in range(PANO.height):
        for col in range(PANO.width):
            d = g_dir(row, col)
            p_rif = np.array([-d[1], d[0], d[2]])    # inverse of (x, y, z)_rif -> (y, -x, z)_G
            u, v = lin_pixel(p_rif, RIG_SIZE)
            if not (4 < u < RIG_SIZE - 4 and 4 < v < RIG_SIZE - 4):
                continue  # away from the replicated borders, where the blend may switch
            np.testing.assert_allclose(label[row, col], 2.0 + 0.1 * (u - 0.5), rtol=1e-5)
            checked += 1
    assert checked > 100


def test_label_blends_to_nearest_at_depth_edges(tmp_path):
    step = np.full((RIG_SIZE, RIG_SIZE), 2.0, np.float32)
    step[:, RIG_SIZE // 2:] = 50.0
    root = build_tree(tmp_path / "step", rig_distance=step, n_frames=1)
    label = ReleaseDatasetReader(root, pano=PANO)[0]["pano_distance"]
    straddling = 0
    for row in range(PANO.height):
        for col in range(PANO.width):
            d = g_dir(row, col)
            u, _ = lin_pixel(np.array([-d[1], d[0], d[2]]), RIG_SIZE)
            straddling += RIG_SIZE // 2 - 0.45 < u < RIG_SIZE // 2 + 0.45
    assert straddling > 0          # plain bilinear would mix 2 m and 50 m at these pixels
    assert set(np.unique(label).tolist()) == {2.0, 50.0}


def test_partitions_and_loader(tree):
    from gijax.data import Loader
    from gijax.train.sources import open_dataset

    reader = open_dataset(tree, "training")
    assert isinstance(reader, ReleaseDatasetReader) and reader.split == "train"
    assert reader[0]["trajectory"] == "EnvA/P000"
    assert open_dataset(tree, "evaluation").split == "validate"
    assert open_dataset(f"{tree}@train", "evaluation").split == "train"
    loader = Loader(reader, batch_size=2, surrogate=Panorama.hemisphere(8, 32), workers=0,
                    shuffle=False)
    batch = next(loader)
    loader.close()
    assert batch["surrogates"].shape == (2, 3, 8, 32, 3)
    np.testing.assert_array_equal(batch["distance"], np.float32(7.25))


def _edit(path: Path, fn) -> None:
    doc = json.loads(path.read_text())
    fn(doc)
    path.write_text(json.dumps(doc))


def test_clear_errors(tree):
    # A missing manifest field.
    _edit(tree / "manifest.json", lambda d: d["camera_models"]["fish_ds"].pop("alpha"))
    with pytest.raises(ValueError, match=r"manifest.json camera_models\['fish_ds'\].*'alpha'"):
        ReleaseDatasetReader(tree, pano=PANO)
    _edit(tree / "manifest.json", lambda d: d["camera_models"]["fish_ds"].update(alpha=0.59))
    # A release camera type gijax has no model for.
    _edit(tree / "manifest.json", lambda d: d["camera_models"]["fish_ds"].update(type="Pinhole"))
    with pytest.raises(ValueError, match="'Pinhole' has no gijax equivalent"):
        ReleaseDatasetReader(tree, pano=PANO)
    _edit(tree / "manifest.json", lambda d: d["camera_models"]["fish_ds"].update(
        type="DoubleSphere"))
    # The label frame missing from the frame graph.
    _edit(tree / "frame_graph.json", lambda d: d.update(
        transforms=[t for t in d["transforms"] if t["f1"] != "rifs"],
        frames=[f for f in d["frames"] if f["name"] != "rifs"]))
    with pytest.raises(ValueError, match="frame_graph.json: no frame 'rifs'"):
        ReleaseDatasetReader(tree, pano=PANO)


def test_missing_files_are_named(tree):
    (tree / "EnvA" / "P000" / "cam1" / "000001_CubeScene.png").unlink()
    with pytest.raises(FileNotFoundError,
                       match=r"000001_CubeScene.png \(.*selected.csv line 3\)"):
        ReleaseDatasetReader(tree, pano=PANO)
    r = ReleaseDatasetReader(tree, pano=PANO, skip_bad=True)
    assert len(r) == 1 and r.skipped[0].line == 3
    _edit(tree / "EnvA" / "P000" / "meta.json", lambda d: d.pop("selected_file_list"))
    with pytest.raises(ValueError, match=r"meta.json: field 'selected_file_list' must be .*; "
                                              r"found nothing \(the field is missing\)$"):
        ReleaseDatasetReader(tree, pano=PANO)
    masks = (tree / "masks.json").read_text()
    (tree / "masks.json").unlink()
    with pytest.raises(FileNotFoundError, match="missing masks file .*masks.json"):
        ReleaseDatasetReader(tree, pano=PANO)
    (tree / "masks.json").write_text(masks)
    (tree / "data_partitions.json").unlink()
    with pytest.raises(FileNotFoundError, match="missing data partitions .*data_partitions.json"):
        ReleaseDatasetReader(tree, pano=PANO)
