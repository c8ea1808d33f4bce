"""Dataset format: bit-exact write -> read, clear errors on bad data, crash-safe resumable
writes."""

from __future__ import annotations

import json
import shutil
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gijax.data import format as fmt
from gijax.data import pngio, writer as writer_mod
from gijax.data.reader import DatasetReader
from gijax.data.writer import DatasetWriter, write_dataset
from gijax.geometry.layouts import TRAIN_BASELINE, synthetic_camera
from gijax.geometry.occluder import Cylinder
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import make_rig, with_occlusion_masks
from gijax.io.rigfile import load_rig

SIZE = 32
PANO = Panorama.hemisphere(8, 32)


def tiny_rig():
    """The paper's training triangle with 32 x 32 equidistant cameras and the LiDAR occluder."""
    angles = np.deg2rad([90.0, 210.0, 330.0])
    r = TRAIN_BASELINE / np.sqrt(3.0)
    pos = np.stack([r * np.cos(angles), r * np.sin(angles), np.zeros(3)], -1)
    cams = [synthetic_camera(SIZE, 300.0 * SIZE / 1024) for _ in range(3)]
    occ = Cylinder(*(np.float32(v) for v in (0.0, 0.0, 0.05, 0.0, 0.1)))
    return with_occlusion_masks(make_rig(cams, np.tile(np.eye(3), (3, 1, 1)), pos, pos[0],
                                         occluder=occ))


def synthetic_sample(rig, i: int, pano: Panorama = PANO) -> dict:
    """Random arrays shaped like a rendered sample (sky = 1e6 m in a few pixels)."""
    rng = np.random.default_rng(1000 + i)
    n = rig.num_cameras
    dist = rng.uniform(0.5, 150.0, (n, SIZE, SIZE)).astype(np.float32)
    dist[:, :2] = 1e6
    pano_d = rng.uniform(0.5, 150.0, pano.shape).astype(np.float32)
    pano_d[0, :4] = 1e6
    pano_d[1, :3] = 0.0  # a label hole: finite but not > 0
    return {"images": rng.integers(0, 256, (n, SIZE, SIZE, 3), dtype=np.uint8),
            "distances": dist,
            "masks": np.stack([np.asarray(m, np.uint8) for m in rig.masks]),
            "pano_distance": pano_d}


@pytest.fixture(scope="module")
def rig():
    return tiny_rig()


@pytest.fixture(scope="module")
def dataset(rig, tmp_path_factory):
    root = tmp_path_factory.mktemp("ds") / "data"
    write_dataset(root, lambda i: synthetic_sample(rig, i), rig, PANO, num_samples=6,
                  trajectory_size=4, seeds=lambda i: 10 * i)
    return root


def _copy(dataset, tmp_path) -> Path:
    dst = tmp_path / "copy"
    shutil.copytree(dataset, dst)
    return dst


# ---------------------------------------------------------------------------- encodings

@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(0, 2**32 - 1), min_size=12, max_size=12))
def test_float32_png_packing_is_bit_exact(bits):
    """Any float32 bit pattern (NaN payloads, inf, denormals) survives PNG encode/decode."""
    words = np.array(bits, np.uint32).reshape(3, 4)
    values = words.view(np.float32)
    packed = pngio.pack_float32(values)
    # Independent reference for the layout: channel k holds byte k of the little-endian word.
    for k in range(4):
        np.testing.assert_array_equal(packed[..., k], (words >> (8 * k)) & 0xFF)
    decoded = cv2.imdecode(np.frombuffer(pngio.encode_distance(values), np.uint8),
                           cv2.IMREAD_UNCHANGED)
    back = pngio.unpack_float32(decoded)
    np.testing.assert_array_equal(back.view(np.uint32), words)


def test_known_float_bytes():
    """1.0f is 0x3F800000: bytes 00 00 80 3F in channels 0..3."""
    packed = pngio.pack_float32(np.array([[1.0, -2.5]], np.float32))
    np.testing.assert_array_equal(packed[0, 0], [0x00, 0x00, 0x80, 0x3F])
    np.testing.assert_array_equal(packed[0, 1], list(struct.pack("<f", -2.5)))


# ---------------------------------------------------------------------------- round trip

def test_write_read_bit_exact(rig, dataset):
    reader = DatasetReader(dataset)
    assert len(reader) == 6
    for i in range(6):
        got, want = reader[i], synthetic_sample(rig, i)
        for key in ("images", "distances", "masks", "pano_distance"):
            assert got[key].dtype == want[key].dtype, key
            np.testing.assert_array_equal(got[key].view(np.uint8), want[key].view(np.uint8))
        assert got["seed"] == 10 * i
        assert (got["trajectory"], got["frame"]) == (f"traj_{i // 4:04d}", i % 4)
    assert reader.pano == PANO


@pytest.mark.parametrize("source", ["reader", "rig_yaml"])
def test_rig_round_trip_bit_exact(rig, dataset, source):
    """The rig comes back exactly through the reader, and from rig/rig.yaml (its one copy)."""
    if source == "reader":
        back = DatasetReader(dataset).rig
    else:
        back = load_rig(dataset / "rig/rig.yaml")
    assert back.names == rig.names
    for a, b in zip(back.cameras, rig.cameras):
        assert type(a) is type(b) and (a.width, a.height) == (b.width, b.height)
        for f in (*b.PARAMS, "fov"):
            assert np.float32(getattr(a, f)) == np.float32(getattr(b, f)), f
    for f in ("rotations", "translations", "reference"):
        np.testing.assert_array_equal(np.asarray(getattr(back, f)), np.asarray(getattr(rig, f)))
    for a, b in zip(back.masks, rig.masks):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    for f in ("x", "y", "radius", "z_min", "z_max"):
        assert np.float32(getattr(back.occluder, f)) == np.float32(getattr(rig.occluder, f))


def test_rig_is_stored_once(rig, dataset):
    """rig/rig.yaml is the dataset's only description of its rig: no frame graph, no cameras,
    poses or occluder in metadata.json, and the manifest names the rig file."""
    names = sorted(p.name for p in dataset.iterdir())
    assert names == ["manifest.json", "metadata.json", "rig", "traj_0000", "traj_0001"]
    assert sorted(p.name for p in (dataset / "rig").iterdir()) == [
        "rig.yaml", "rig_cam0_mask.png", "rig_cam1_mask.png", "rig_cam2_mask.png"]
    meta = json.loads((dataset / "metadata.json").read_text())
    assert sorted(meta) == ["distance_range", "encodings", "panorama", "sky_distance"]
    manifest = json.loads((dataset / "manifest.json").read_text())
    assert (manifest["version"], manifest["rig"]) == (2, "rig/rig.yaml")
    assert "frame_graph" not in manifest


def _as_version_1(root: Path, rig) -> None:
    """Rewrite a dataset as format version 1 wrote it: the rig also in metadata.json (cameras,
    occluder) and frame_graph.json (camera-to-rig poses, panorama centre)."""
    manifest = json.loads((root / "manifest.json").read_text())
    manifest.update(version=1, frame_graph="frame_graph.json")
    (root / "manifest.json").write_text(json.dumps(manifest))
    meta = json.loads((root / "metadata.json").read_text())
    meta["cameras"] = [{"name": n, "model": "equidistant", "width": SIZE, "height": SIZE,
                        "intrinsics": {k: float(getattr(c, k)) for k in ("fx", "fy", "cx", "cy")},
                        "fov_rad": float(c.fov), "mask": f"rig/rig_{n}_mask.png"}
                       for n, c in zip(rig.names, rig.cameras)]
    meta["occluder"] = {"type": "cylinder", "x": 0.0, "y": 0.0, "radius": float(np.float32(0.05)),
                        "z_min": 0.0, "z_max": float(np.float32(0.1))}
    (root / "metadata.json").write_text(json.dumps(meta))
    frames = {"rig": {"parent": None},
              "pano": {"parent": "rig", "rotation": np.eye(3).tolist(),
                       "translation": np.asarray(rig.reference, np.float64).tolist()}}
    for i, n in enumerate(rig.names):
        frames[n] = {"parent": "rig", "rotation": np.eye(3).tolist(),
                     "translation": np.asarray(rig.translations[i], np.float64).tolist()}
    (root / "frame_graph.json").write_text(json.dumps({"frames": frames}))


def test_version_1_datasets_read_and_copies_that_disagree_are_refused(rig, dataset, tmp_path):
    root = _copy(dataset, tmp_path)
    _as_version_1(root, rig)
    back = DatasetReader(root)
    assert fmt.rig_differences(back.rig, load_rig(dataset / "rig/rig.yaml")) == []
    np.testing.assert_array_equal(np.asarray(back.rig.translations),
                                  np.asarray(rig.translations, np.float32))
    np.testing.assert_array_equal(back[1]["images"], synthetic_sample(rig, 1)["images"])
    # An old dataset is confirmed (same panorama, rig and settings) and left as it is: asking
    # for what it holds writes nothing; appending to it is refused.
    before = _tree(root)
    with DatasetWriter(root, rig, PANO) as old:
        old.request(old.num_committed)
        with pytest.raises(ValueError, match=r"format version 1 .* use a new output folder"):
            old.write(synthetic_sample(rig, 99))
        with pytest.raises(ValueError, match=r"format version 1 .* use a new output folder"):
            old.request(old.num_committed + 1)
    assert _tree(root) == before
    graph = json.loads((root / "frame_graph.json").read_text())
    graph["frames"]["cam1"]["translation"][0] += 0.001
    (root / "frame_graph.json").write_text(json.dumps(graph))
    with pytest.raises(ValueError) as exc:
        DatasetReader(root)
    msg = str(exc.value)
    assert "\n" not in msg and "translations" in msg and "disagree" in msg
    assert "frame_graph.json" in msg and str(root / "rig" / "rig.yaml") in msg
    (root / "rig" / "rig.yaml").unlink()            # version 1 before it held a rig file
    manifest = json.loads((root / "manifest.json").read_text())
    del manifest["rig"]
    (root / "manifest.json").write_text(json.dumps(manifest))
    moved = DatasetReader(root).rig
    assert float(moved.translations[1][0]) == np.float32(float(np.float32(rig.translations[1][0]))
                                                         + 0.001)


def test_resume_refuses_another_rig(rig, dataset, tmp_path):
    root = _copy(dataset, tmp_path)
    other = rig.replace(translations=np.asarray(rig.translations) * 1.01)
    with pytest.raises(ValueError, match=r"rig\.yaml differs from the rig being written "
                                         r"\(translations\)"):
        DatasetWriter(root, other, PANO)


def test_on_disk_conventions(rig, dataset):
    """RGB files hold BGR channel order (OpenCV), masks 0/255, the CSV lists paths per column."""
    want = synthetic_sample(rig, 1)
    raw = cv2.imread(str(dataset / "traj_0000/cam2/rgb/000001.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(raw, want["images"][2][..., ::-1])
    m = cv2.imread(str(dataset / "traj_0000/cam0/mask/000001.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(m, want["masks"][0] * 255)
    lines = (dataset / "traj_0001/files.csv").read_text().splitlines()
    assert lines[0].split(",") == fmt.file_columns(rig.names)
    assert len(lines) == 3  # header + frames 0 and 1 of the second trajectory
    manifest = json.loads((dataset / "manifest.json").read_text())
    assert [t["file_list"] for t in manifest["trajectories"]] == ["traj_0000/files.csv",
                                                                  "traj_0001/files.csv"]


# ---------------------------------------------------------------------------- bad input

def test_missing_file_names_file_and_row(dataset, tmp_path):
    root = _copy(dataset, tmp_path)
    victim = root / "traj_0001/cam1/distance/000001.png"
    victim.unlink()
    with pytest.raises(FileNotFoundError, match=r"000001\.png.*traj_0001[/\\]files\.csv line 3"):
        DatasetReader(root)
    lazy = DatasetReader(root, verify="none")
    with pytest.raises(FileNotFoundError, match=str(victim).replace("\\", "\\\\")):
        lazy[5]


def test_truncated_file_names_file_and_row(dataset, tmp_path):
    root = _copy(dataset, tmp_path)
    victim = root / "traj_0000/cam0/rgb/000002.png"
    victim.write_bytes(victim.read_bytes()[:-40])
    reader = DatasetReader(root)  # the file exists, so opening succeeds
    with pytest.raises(ValueError, match=r"cam0/rgb/000002\.png is truncated.*files\.csv line 4"):
        reader[2]
    with pytest.raises(ValueError, match="truncated"):
        DatasetReader(root, verify="full")


def test_wrong_channels_and_size(rig, dataset, tmp_path):
    root = _copy(dataset, tmp_path)
    rgb = root / "traj_0000/cam1/distance/000000.png"
    rgb.write_bytes(pngio.encode_rgb(np.zeros((SIZE, SIZE, 3), np.uint8)))
    small = root / "traj_0000/cam2/rgb/000001.png"
    small.write_bytes(pngio.encode_rgb(np.zeros((SIZE, SIZE - 2, 3), np.uint8)))
    reader = DatasetReader(root)
    with pytest.raises(ValueError, match=r"distance/000000\.png: packed distance must have 4 "
                                         r"channel\(s\); found 3.*line 2"):
        reader[0]
    with pytest.raises(ValueError, match=r"rgb/000001\.png: RGB image must be 32x32 \(WxH\); "
                                         r"found 30x32.*line 3"):
        reader[1]


def test_non_finite_distance(dataset, tmp_path):
    root = _copy(dataset, tmp_path)
    d = np.full(PANO.shape, 3.0, np.float32)
    d[2, 5] = np.nan
    d[3, 1] = np.inf
    (root / "traj_0000/pano/distance/000003.png").write_bytes(pngio.encode_distance(d))
    with pytest.raises(ValueError, match=r"pano/distance/000003\.png: 2 non-finite.*line 5"):
        DatasetReader(root)[3]


def test_manifest_errors(dataset, tmp_path):
    root = _copy(dataset, tmp_path)
    manifest = root / "manifest.json"
    good = manifest.read_text()
    manifest.unlink()
    with pytest.raises(FileNotFoundError, match=r"missing manifest .*manifest\.json"):
        DatasetReader(root)
    manifest.write_text(good[:-30])
    with pytest.raises(ValueError, match=r"malformed manifest .*manifest\.json: .* line \d+"):
        DatasetReader(root)
    doc = json.loads(good)
    del doc["trajectories"]
    manifest.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"manifest\.json: field 'trajectories' must be a list; "
                       r"found nothing \(the field is missing\)$"):
        DatasetReader(root)
    doc = json.loads(good)
    doc["trajectories"][1] = {"name": "traj_0001"}
    manifest.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"trajectories\[1\]: field 'file_list' must be a string; "
                       r"found nothing \(the field is missing\)$"):
        DatasetReader(root)


def test_names_that_lead_outside_the_dataset_are_refused(dataset, tmp_path):
    """A file list, a manifest entry or a mask name may only point inside the dataset folder:
    ``../`` out of it or an absolute path is refused naming the document, line and column,
    and the file outside is never opened."""
    root = _copy(dataset, tmp_path)
    outside = tmp_path / "secret.png"
    outside.write_bytes(b"not a dataset file")
    csv_path = root / "traj_0000/files.csv"
    lines = csv_path.read_text().splitlines()
    cells = lines[1].split(",")
    header = lines[0].split(",")
    col = header.index("cam0_rgb")
    for bad, match in (("../../secret.png", "leads outside the dataset folder"),
                       (str(outside), "is an absolute path")):
        cells[col] = bad
        csv_path.write_text("\n".join([lines[0], ",".join(cells)] + lines[2:]) + "\n")
        with pytest.raises(ValueError, match=rf"column 'cam0_rgb', .*files\.csv line 2: .*{match}"):
            DatasetReader(root)
    csv_path.write_text("\n".join(lines) + "\n")
    manifest = root / "manifest.json"
    doc = json.loads(manifest.read_text())
    doc["trajectories"][0]["file_list"] = "../" + root.name + "/../secret.png"
    manifest.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"trajectory 'traj_0000' field 'file_list': .* leads "
                                         r"outside"):
        DatasetReader(root)


def test_csv_errors(dataset, tmp_path):
    root = _copy(dataset, tmp_path)
    csv_path = root / "traj_0000/files.csv"
    lines = csv_path.read_text().splitlines()
    csv_path.write_text("\n".join(lines[:3] + [lines[3] + ",extra"] + lines[4:]) + "\n")
    with pytest.raises(ValueError, match=r"traj_0000[/\\]files\.csv line 4: expected 12 fields, "
                                         r"found 13"):
        DatasetReader(root)
    header = lines[0].replace("cam1_rgb", "cam1_colour")
    csv_path.write_text("\n".join([header] + lines[1:]) + "\n")
    with pytest.raises(ValueError, match=r"files\.csv line 1: header lacks column\(s\) "
                                         r"\['cam1_rgb'\]"):
        DatasetReader(root)


def test_skip_bad_counts_and_reports(dataset, tmp_path):
    root = _copy(dataset, tmp_path)
    (root / "traj_0000/cam0/mask/000001.png").unlink()
    (root / "traj_0001/pano/distance/000000.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    with pytest.warns(UserWarning, match="2 bad row"):
        reader = DatasetReader(root, skip_bad=True, verify="full")
    assert len(reader) == 4
    assert [(Path(s.file_list).parent.name, s.line) for s in reader.skipped] == [
        ("traj_0000", 3), ("traj_0001", 2)]
    assert "missing file" in reader.skipped[0].reason
    assert "truncated" in reader.skipped[1].reason
    assert [reader[i]["frame"] for i in range(4)] == [0, 2, 3, 1]
    assert "line 3" in reader.report() and "line 2" in reader.report()


def test_writer_rejects_bad_samples(rig, tmp_path):
    w = DatasetWriter(tmp_path / "w", rig, PANO)
    s = synthetic_sample(rig, 0)
    with pytest.raises(ValueError, match=r"distances\[1\] \(cam1\) must be float32"):
        w.write({**s, "distances": [s["distances"][0], s["distances"][1].astype(np.float64),
                                    s["distances"][2]]})
    bad = s["pano_distance"].copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="pano_distance has non-finite"):
        w.write({**s, "pano_distance": bad})
    with pytest.raises(ValueError, match=r"images' has 2 cameras; the rig has 3"):
        w.write({**s, "images": s["images"][:2]})
    assert w.num_committed == 0 and not (tmp_path / "w/traj_0000/files.csv").exists()


# ---------------------------------------------------------------------------- crash safety

def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


class Crash(RuntimeError):
    pass


def test_interrupted_write_resumes_to_identical_data(rig, dataset, tmp_path, monkeypatch):
    calls = []

    def make(i):
        calls.append(i)
        return synthetic_sample(rig, i)

    out = tmp_path / "resumed"
    kw = dict(num_samples=6, trajectory_size=4, seeds=lambda i: 10 * i)
    real_write = writer_mod.write_bytes_atomic
    count = {"n": 0}

    # Crash 1: in the middle of writing a file of sample 2 (its 6th file), leaving a partial.
    def dying_write(path, data, **kw):
        if "000002" in Path(path).name:
            count["n"] += 1
            if count["n"] == 6:
                Path(str(path) + pngio.PARTIAL_SUFFIX).write_bytes(data[: len(data) // 2])
                raise Crash("power cut")
        return real_write(path, data, **kw)

    monkeypatch.setattr(writer_mod, "write_bytes_atomic", dying_write)
    with pytest.raises(Crash):
        write_dataset(out, make, rig, PANO, **kw)
    with pytest.raises(ValueError, match=r"incomplete: 2 of the 6 samples"):
        DatasetReader(out)  # the manifest knows 6 were requested
    with pytest.warns(UserWarning, match=r"2 of the 6"):
        reader = DatasetReader(out, allow_partial=True)
    assert len(reader) == 2  # samples 0, 1; nothing of sample 2 looks complete
    assert list((out / "traj_0000").rglob("*.partial"))

    # Crash 2: after every file and the CSV of sample 4 exist, before the manifest lists them.
    monkeypatch.setattr(writer_mod, "write_bytes_atomic", real_write)
    monkeypatch.setattr(DatasetWriter, "_write_manifest",
                        lambda self: (_ for _ in ()).throw(Crash("killed")))
    with pytest.raises(Crash):
        write_dataset(out, make, rig, PANO, **kw)
    assert (out / "traj_0001/files.csv").exists()
    with pytest.warns(UserWarning, match=r"4 of the 6"):
        assert len(DatasetReader(out, allow_partial=True)) == 4  # traj_0001 not listed yet
    monkeypatch.undo()

    calls.clear()
    assert write_dataset(out, make, rig, PANO, **kw) == 2
    assert calls == [4, 5]  # committed samples are not recomputed
    assert not list(out.rglob("*.partial"))
    assert _tree(out) == _tree(dataset)  # byte-identical to the uninterrupted run
    assert write_dataset(out, make, rig, PANO, **kw) == 0  # complete: nothing to do


def test_resume_refuses_other_settings(rig, dataset, tmp_path):
    root = _copy(dataset, tmp_path)
    other_pano = Panorama.hemisphere(8, 16)
    with pytest.raises(ValueError, match=r"metadata\.json differs .*panorama"):
        DatasetWriter(root, rig, other_pano)
    with pytest.raises(ValueError, match="generator settings"):
        DatasetWriter(root, rig, PANO, generator={"seed": 3})
    stray = tmp_path / "stray"
    stray.mkdir()
    (stray / "notes.txt").write_text("x")
    with pytest.raises(ValueError, match="not empty and has no manifest.json"):
        DatasetWriter(stray, rig, PANO)


def _version_1_without_rig_file(root: Path, rig) -> None:
    _as_version_1(root, rig)
    (root / "rig" / "rig.yaml").unlink()
    manifest = json.loads((root / "manifest.json").read_text())
    del manifest["rig"]
    (root / "manifest.json").write_text(json.dumps(manifest))


@pytest.mark.parametrize("doc, field, edit, expected", [
    ("metadata.json", "intrinsics.fx", lambda d: d["cameras"][1]["intrinsics"].update(fx=float("nan")),
     "one finite number"),
    ("metadata.json", "intrinsics.fy", lambda d: d["cameras"][1]["intrinsics"].update(fy=-3.0),
     "a positive focal length"),
    ("metadata.json", "resolution", lambda d: d["cameras"][1].update(width=10**6, height=10**6),
     "32768-pixel bound"),
    ("frame_graph.json", "rotation",
     lambda d: d["frames"]["cam1"].update(rotation=[[1, 0, 0], [0, 1, 0], [0, 0, 2]]),
     "a proper orthonormal 3x3 rotation"),
    ("frame_graph.json", "translation",
     lambda d: d["frames"]["cam1"].update(translation=[0.1, float("inf"), 0.0]),
     "finite numbers"),
])
def test_a_dataset_calibration_is_checked_like_a_rig_file(rig, dataset, tmp_path, doc, field,
                                                          edit, expected):
    root = _copy(dataset, tmp_path)
    _version_1_without_rig_file(root, rig)
    body = json.loads((root / doc).read_text())
    edit(body)
    (root / doc).write_text(json.dumps(body))
    with pytest.raises(ValueError) as exc:
        DatasetReader(root)
    msg = str(exc.value)
    assert "\n" not in msg and str(root / doc) in msg and "'cam1'" in msg
    assert f"field {field!r}" in msg and expected in msg
