"""Atomic writes: files get the mode the umask allows (not the 0600 of a private temporary), a
failed write leaves the old file and no temporary, and every writer goes through the one helper."""

from __future__ import annotations

import contextlib
import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from gijax.io.paths import atomic_path, write_bytes_atomic, write_text_atomic


@contextlib.contextmanager
def umask(mask: int):
    old = os.umask(mask)
    try:
        yield
    finally:
        os.umask(old)


def mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _write_bytes(path):
    write_bytes_atomic(path, b"\x00\x01bytes")


def _write_text(path):
    write_text_atomic(path, "text \u00e9\n")


def _write_through_path(path):
    with atomic_path(path) as tmp:
        tmp.write_bytes(b"by name")


@pytest.mark.parametrize("write", [_write_bytes, _write_text, _write_through_path])
@pytest.mark.parametrize("mask, expected", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_mode_is_0666_less_the_umask(tmp_path, write, mask, expected):
    target = tmp_path / "out.bin"
    with umask(mask):
        write(target)                 # a new file
    assert mode(target) == expected
    target.chmod(0o400)               # replacing a file gives the new one the umask's mode too
    with umask(mask):
        write(target)
    assert mode(target) == expected
    assert names(tmp_path) == ["out.bin"]


def test_content_and_encoding(tmp_path):
    write_text_atomic(tmp_path / "t.txt", "caf\u00e9\n")
    assert (tmp_path / "t.txt").read_bytes() == b"caf\xc3\xa9\n"
    write_bytes_atomic(tmp_path / "b.bin", bytes(range(256)))
    assert (tmp_path / "b.bin").read_bytes() == bytes(range(256))


def test_failure_mid_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "keep.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="disk full"):
        with atomic_path(target) as tmp:
            tmp.write_text("new, but only ha")
            raise RuntimeError("disk full")
    assert target.read_text() == "old"
    assert names(tmp_path) == ["keep.txt"]
    with pytest.raises(TypeError):                 # fails inside the write itself
        write_bytes_atomic(target, "not bytes")
    assert target.read_text() == "old"
    assert names(tmp_path) == ["keep.txt"]
    (tmp_path / "folder").mkdir()                  # fails at the rename
    with pytest.raises(IsADirectoryError):
        write_text_atomic(tmp_path / "folder", "x")
    assert names(tmp_path) == ["folder", "keep.txt"] and names(tmp_path / "folder") == []


def test_temporary_is_hidden_beside_the_target_and_keeps_its_extension(tmp_path):
    """Writers that pick the format by extension (cv2.imwrite) or add one (np.save) see the
    destination's extension, and the temporary lives in the destination's folder."""
    seen = []
    array = np.arange(6, dtype=np.float32).reshape(2, 3)
    with atomic_path(tmp_path / "a.npy") as tmp:
        seen.append(tmp)
        assert tmp.exists() and tmp.stat().st_size == 0
        np.save(tmp, array)
    assert seen[0].parent == tmp_path and seen[0].name.startswith(".a.npy.")
    assert seen[0].name.endswith(".tmp.npy") and not seen[0].exists()
    np.testing.assert_array_equal(np.load(tmp_path / "a.npy"), array)
    assert names(tmp_path) == ["a.npy"]
    with atomic_path(tmp_path / "b.png", suffix=".partial") as tmp:
        assert tmp.name.endswith(".partial")
        tmp.write_bytes(b"x")
    assert names(tmp_path) == ["a.npy", "b.png"]


def test_long_names_stay_within_the_file_name_limit(tmp_path):
    name = "n" * 250 + ".json"
    write_text_atomic(tmp_path / name, "{}")
    assert names(tmp_path) == [name]


# --------------------------------------------------------------- every writer, under umask 022


def _tiny_rig_with_mask():
    from gijax.geometry.cameras import make_camera
    from gijax.geometry.rig import make_rig

    cam = make_camera("equidistant", dict(fx=10.0, fy=10.0, cx=7.5, cy=5.5), 16, 12, 180.0)
    mask = np.ones((12, 16), np.float32)
    mask[:3, :4] = 0.0
    return make_rig([cam, cam], np.tile(np.eye(3), (2, 1, 1)), [[0, 0, 0], [0.2, 0, 0]],
                    masks=[None, mask], names=["a", "b"])


def test_rig_file_and_mask_are_readable_by_others(tmp_path):
    from gijax.io.rigfile import load_rig, save_rig

    with umask(0o022):
        path = save_rig(_tiny_rig_with_mask(), tmp_path / "rig.yaml")
    assert names(tmp_path) == ["rig.yaml", "rig_b_mask.png"]
    assert {n: mode(tmp_path / n) for n in names(tmp_path)} == {"rig.yaml": 0o644,
                                                                "rig_b_mask.png": 0o644}
    back = load_rig(path)
    assert float(np.asarray(back.masks[1]).sum()) == 16 * 12 - 3 * 4


def test_dataset_and_colour_map_are_readable_by_others(tmp_path):
    from test_data_format import PANO, synthetic_sample, tiny_rig

    from gijax.data.writer import write_dataset
    from gijax.viz.colormap import save_panorama_png

    rig = tiny_rig()
    with umask(0o022):
        write_dataset(tmp_path / "ds", lambda i: synthetic_sample(rig, i), rig, PANO,
                      num_samples=1, durable=True)
        save_panorama_png(str(tmp_path / "c.png"), np.linspace(0, 1, 32).reshape(4, 8),
                          "t", 0.0, 1.0, dpi=20)
    files = [p for p in (tmp_path / "ds").rglob("*") if p.is_file() and "lock" not in p.name]
    assert len(files) == 1 + 1 + 4 + 1 + 3 * 3 + 1   # manifest, metadata, rig, CSV, PNGs
    assert {mode(p) for p in files} == {0o644} and mode(tmp_path / "c.png") == 0o644
    assert (tmp_path / "c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _figure():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(1, 1))
    ax.plot([0, 1], [1, 0])
    return fig


def test_format_writers_round_trip_with_the_umask_mode(tmp_path):
    import cv2

    from gijax.io.paths import save_figure_atomic, save_npy_atomic, write_json_atomic, \
        write_png_atomic

    array = np.arange(6, dtype=np.float32).reshape(2, 3)
    rgb = np.zeros((2, 3, 3), np.uint8)
    rgb[0, 0] = (255, 0, 0)                       # red, stored as OpenCV's BGR
    deep = np.array([[0, 1, 65535]], np.uint16)
    with umask(0o022):
        write_json_atomic(tmp_path / "sub" / "a.json", {"x": [1, 2.5]})   # makes the folder
        save_npy_atomic(tmp_path / "b.npy", array)
        write_png_atomic(tmp_path / "c.png", rgb)
        write_png_atomic(tmp_path / "d.png", deep)
        fig = _figure()
        save_figure_atomic(fig, tmp_path / "e.png", dpi=20)
    assert names(tmp_path) == ["b.npy", "c.png", "d.png", "e.png", "sub"]
    assert (tmp_path / "sub" / "a.json").read_text() == '{\n  "x": [\n    1,\n    2.5\n  ]\n}\n'
    np.testing.assert_array_equal(np.load(tmp_path / "b.npy"), array)
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "c.png"))[0, 0], [0, 0, 255])
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED), deep)
    assert (tmp_path / "e.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert {mode(p) for p in tmp_path.rglob("*") if p.is_file()} == {0o644}


def test_a_writer_that_fails_midway_leaves_no_partial_file(tmp_path, monkeypatch):
    """Each writer is made to fail after it has written part of its temporary: the destination
    keeps its old content (or stays absent) and no temporary is left."""
    from gijax.io import paths

    def half_then_fail(tmp, *args, **kwargs):
        Path(tmp).write_bytes(b"half")
        raise OSError("disk full")

    (tmp_path / "old.npy").write_bytes(b"old")
    monkeypatch.setattr(np, "save", half_then_fail)
    with pytest.raises(OSError, match="disk full"):
        paths.save_npy_atomic(tmp_path / "old.npy", np.zeros(3))
    fig = _figure()
    monkeypatch.setattr(fig, "savefig", half_then_fail)
    with pytest.raises(OSError, match="disk full"):
        paths.save_figure_atomic(fig, tmp_path / "new.png")
    real_fsync = os.fsync

    def failing_fsync(fd):                       # the content is written, the flush fails
        raise OSError("I/O error")

    monkeypatch.setattr(os, "fsync", failing_fsync)
    with pytest.raises(OSError, match="I/O error"):
        paths.write_json_atomic(tmp_path / "new.json", {"a": 1})
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert names(tmp_path) == ["old.npy"] and (tmp_path / "old.npy").read_bytes() == b"old"


def test_run_config_bench_report_and_point_cloud_are_readable_by_others(tmp_path):
    from gijax.bench.report import write_json
    from gijax.train.config import TrainConfig, save_run_config
    from gijax.viz.pointcloud import write_ply

    with umask(0o022):
        save_run_config(tmp_path, TrainConfig(), [0.5, 1.0, 100.0], "paper-train")
        write_json(tmp_path / "bench.json", {"x": np.float32(1.5)})
        write_ply(str(tmp_path / "p.ply"), np.zeros((3, 3), np.float32))
    assert {n: mode(tmp_path / n) for n in names(tmp_path)} == {
        "bench.json": 0o644, "config.json": 0o644, "p.ply": 0o644}
    assert json.loads((tmp_path / "config.json").read_text())["candidates"] == [0.5, 1.0, 100.0]
    assert json.loads((tmp_path / "bench.json").read_text()) == {"x": 1.5}


def test_onnx_file_is_readable_by_others(tmp_path):
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    from gijax.export.onnx_export import _save_atomic

    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])
    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g", [x],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])
    with umask(0o022):
        _save_atomic(helper.make_model(graph), tmp_path / "m.onnx")
    assert names(tmp_path) == ["m.onnx"] and mode(tmp_path / "m.onnx") == 0o644
    assert onnx.load(str(tmp_path / "m.onnx")).graph.node[0].op_type == "Identity"
