"""Corrupted documents: every reader answers a damaged rig, calibration, dataset, release-layout
or bundle document with one clear error or a valid object.

Each reader starts from a valid document written by the project's own writer (a small rig, a
tiny dataset, a bundle's documents) or, for formats gijax only reads (Kalibr, basalt, the
release layout), by the tests that pin those formats. Hypothesis then damages one document: it
deletes a key, changes a value's type (text, number, list, mapping, null, bool), puts NaN,
infinity, a huge, zero or negative number in its place, nudges a number (a rotation stops
being orthonormal, a quaternion stops being a unit), wraps a value in a list or a mapping,
duplicates a list entry (a camera twice), or damages the text itself (cut at a byte, bytes
flipped). The reader must then either

* raise the error the command line prints as one line (``ValueError`` or
  ``FileNotFoundError``, see :func:`gijax.cli.main`) with a message of one line that names
  the file, or
* return an object whose numbers are finite and whose rotations are rotations,

within a time limit: no other exception (a traceback for the user), no hang, no NaN let in.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import math
import os
import shutil
import signal
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gijax.data import check as check_mod
from gijax.data import format as fmt
from gijax.data.reader import DatasetReader
from gijax.data.writer import write_dataset
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import Rig
from gijax.io.rigfile import load_rig, save_rig
from gijax.store import bundles, configs, envelope
from gijax.nn.presets import get_preset

# The one import of the release-layout reader (its module may move).
from gijax.data.release import ReleaseDatasetReader  # noqa: E402

from test_data_format import _as_version_1, synthetic_sample, tiny_rig  # noqa: E402
from test_release_layout import build_tree  # noqa: E402

EXAMPLES = int(os.environ.get("GIJAX_CORRUPT_EXAMPLES", "40"))          # per document
TIME_LIMIT_S = 5.0      # per example: a reader that takes longer is hanging
CLEAR_ERRORS = (ValueError, FileNotFoundError)
PANO = Panorama.hemisphere(8, 32)
SMALL_LABEL_PANO = Panorama.hemisphere(4, 16)


# ------------------------------------------------------------------------------- damage

BAD_NUMBERS = (math.nan, math.inf, -math.inf, 1e300, -1e300, 0, -1, -0.5, 2 ** 31, 10 ** 12,
               1e-300)
OTHER_TYPES = ("text", "", 3, 2.5, [], [1, 2], {}, {"a": 1}, None, True)


def _nodes(doc, path=()):
    """Every node of a decoded document as a key path (the root is ``()``)."""
    yield path
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _nodes(v, path + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _nodes(v, path + (i,))


def _get(doc, path):
    for k in path:
        doc = doc[k]
    return doc


def _set(doc, path, value):
    if not path:
        return value
    _get(doc, path[:-1])[path[-1]] = value
    return doc


def damage_structure(doc, draw):
    """One random structural change of a decoded JSON / YAML document (a deep copy)."""
    doc = copy.deepcopy(doc)
    paths = list(_nodes(doc))
    kind = draw(st.sampled_from(("delete", "retype", "number", "nudge", "nest", "duplicate")))
    if kind == "nudge":
        numeric = [p for p in paths if isinstance(_get(doc, p), (int, float))
                   and not isinstance(_get(doc, p), bool)]
        if numeric:
            p = draw(st.sampled_from(numeric))
            return _set(doc, p, _get(doc, p) * draw(st.sampled_from((1.5, -1.0, 0.9))) +
                        draw(st.sampled_from((0.0, 0.1))))
        kind = "number"
    if kind == "duplicate":
        lists = [p for p in paths if isinstance(_get(doc, p), list) and _get(doc, p)]
        if lists:
            p = draw(st.sampled_from(lists))
            items = _get(doc, p)
            items.append(copy.deepcopy(items[draw(st.integers(0, len(items) - 1))]))
            return doc
        kind = "delete"
    if kind == "delete" and len(paths) > 1:
        p = draw(st.sampled_from(paths[1:]))
        del _get(doc, p[:-1])[p[-1]]
        return doc
    p = draw(st.sampled_from(paths))
    if kind == "number":
        return _set(doc, p, draw(st.sampled_from(BAD_NUMBERS)))
    if kind == "nest":
        old = _get(doc, p)
        return _set(doc, p, draw(st.sampled_from(([old], {"value": old}))))
    return _set(doc, p, copy.deepcopy(draw(st.sampled_from(OTHER_TYPES))))


def damage_bytes(data: bytes, draw) -> bytes:
    """The file's bytes cut at a random byte, or with a few bytes flipped."""
    if draw(st.booleans()):
        return data[:draw(st.integers(0, max(len(data) - 1, 0)))]
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, len(out) - 1))
        out[i] ^= draw(st.integers(1, 255))
    return bytes(out)


def _dump(doc, kind: str) -> bytes:
    if kind == "json":
        return json.dumps(doc).encode()      # NaN and Infinity as Python's json writes them
    return yaml.safe_dump(doc, sort_keys=False).encode()


def damaged(original: bytes, kind: str, draw) -> bytes:
    if kind == "text" or draw(st.integers(0, 3)) == 0:
        return damage_bytes(original, draw)
    doc = json.loads(original) if kind == "json" else yaml.safe_load(original)
    return _dump(damage_structure(doc, draw), kind)


# ------------------------------------------------------------------------------- checks

class Hang(BaseException):
    """Raised by the alarm (a BaseException, so that no reader's handler swallows it)."""


def _alarm(signum, frame):
    raise Hang()


def _finite(x, what):
    arr = np.asarray(x)
    if arr.dtype.kind in "fc":
        assert np.all(np.isfinite(arr)), f"non-finite {what} accepted: {arr}"


def check_rig(rig: Rig):
    assert isinstance(rig, Rig) and rig.num_cameras >= 1
    for i, cam in enumerate(rig.cameras):
        for k in (*cam.PARAMS, "fov"):
            _finite(getattr(cam, k), f"camera {i} {k}")
        assert int(cam.width) >= 1 and int(cam.height) >= 1
        assert 0.0 < float(cam.fov) <= 2 * math.pi + 1e-6, float(cam.fov)
        assert float(cam.fx) > 0 and float(cam.fy) > 0
    for field in ("rotations", "translations", "reference", "panorama_rotation"):
        _finite(getattr(rig, field), field)
    for r in list(np.asarray(rig.rotations, np.float64)) + [np.asarray(rig.panorama_rotation,
                                                                      np.float64)]:
        assert np.abs(r.T @ r - np.eye(3)).max() < 1e-4 and np.linalg.det(r) > 0, r
    if rig.occluder is not None:
        for k in ("x", "y", "radius", "z_min", "z_max"):
            _finite(getattr(rig.occluder, k), f"occluder {k}")
    for cam, m in zip(rig.cameras, rig.masks):
        assert m is None or tuple(np.shape(m)) == (cam.height, cam.width)


def check_dataset_reader(reader):
    check_rig(reader.rig)
    pano = reader.pano
    assert pano.height >= 1 and pano.width >= 1
    _finite([pano.lat_min, pano.lat_max], "panorama latitudes")
    assert pano.lat_min < pano.lat_max
    lo, hi = reader.distance_range
    _finite([lo, hi, reader.sky_distance], "distance range / sky distance")
    assert 0 < lo < hi and reader.sky_distance > 0
    if len(reader):
        reader[0]


def clear_or_valid(read, check, names):
    """``read()`` under the time limit: a one-line clear error naming one of ``names``, or an
    object that passes ``check``."""
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, TIME_LIMIT_S)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                obj = read()
            except CLEAR_ERRORS as exc:
                msg = str(exc)
                assert msg and "\n" not in msg, f"error message of more than one line: {msg!r}"
                assert any(n in msg for n in names), f"error names none of {names}: {msg!r}"
                return
            check(obj)
    except Hang:
        pytest.fail(f"reader took more than {TIME_LIMIT_S} s")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


# ------------------------------------------------------------------------------- documents

def _rig_file(folder: Path) -> Path:
    # A turned panorama frame, so that the file holds every optional field.
    rig = dataclasses.replace(tiny_rig(), panorama_rotation=np.asarray(
        [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], np.float32))
    return save_rig(rig, folder / "rig.yaml")


KALIBR = {
    "cam0": {"camera_model": "ds", "intrinsics": [-0.2, 0.59, 10.0, 10.5, 15.5, 15.5],
             "distortion_model": "none", "distortion_coeffs": [], "resolution": [32, 32]},
    "cam1": {"camera_model": "eucm", "intrinsics": [0.6, 1.1, 10.0, 10.0, 15.5, 15.5],
             "distortion_model": "none", "resolution": [32, 32],
             "T_cn_cnm1": [[0.0, -1.0, 0.0, 0.2], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0],
                           [0.0, 0.0, 0.0, 1.0]]},
    "cam2": {"camera_model": "pinhole", "intrinsics": [9.0, 9.0, 15.5, 15.5],
             "distortion_model": "equidistant", "distortion_coeffs": [0.01, -0.002, 0.0, 0.0],
             "resolution": [32, 32],
             "T_cn_cnm1": [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.2], [0.0, 0.0, 1.0, 0.0],
                           [0.0, 0.0, 0.0, 1.0]]},
}

_S = math.sqrt(0.5)
BASALT = {"value0": {
    "T_imu_cam": [{"px": x, "py": y, "pz": 0.0, "qx": 0.0, "qy": 0.0, "qz": qz, "qw": qw}
                  for x, y, qz, qw in ((0.0, 0.0, 0.0, 1.0), (0.3, 0.0, _S, _S),
                                       (0.3, 0.3, 1.0, 0.0))],
    "intrinsics": [{"camera_type": "ds", "intrinsics": {"fx": 12.0, "fy": 12.0, "cx": 15.5,
                                                        "cy": 15.5, "xi": -0.2, "alpha": 0.6}},
                   {"camera_type": "eucm", "intrinsics": {"fx": 12.0, "fy": 12.0, "cx": 15.5,
                                                          "cy": 15.5, "alpha": 0.6,
                                                          "beta": 1.1}},
                   {"camera_type": "kb4", "intrinsics": {"fx": 9.0, "fy": 9.0, "cx": 15.5,
                                                         "cy": 15.5, "k1": 0.01, "k2": 0.0,
                                                         "k3": 0.0, "k4": 0.0}}],
    "resolution": [[32, 32], [32, 32], [32, 32]],
}}


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """One valid copy of each kind of document, in its own folder."""
    base = tmp_path_factory.mktemp("valid")
    out = {}
    out["rig"] = base / "rig"
    out["rig"].mkdir()
    _rig_file(out["rig"])
    out["kalibr"] = base / "kalibr"
    out["kalibr"].mkdir()
    (out["kalibr"] / "camchain.yaml").write_text(yaml.safe_dump(KALIBR))
    out["basalt"] = base / "basalt"
    out["basalt"].mkdir()
    (out["basalt"] / "calibration.json").write_text(json.dumps(BASALT))
    rig = tiny_rig()
    out["dataset"] = base / "dataset"
    write_dataset(out["dataset"], lambda i: synthetic_sample(rig, i), rig, PANO, num_samples=2,
                  trajectory_size=2, seeds=lambda i: i)
    out["dataset_v1"] = base / "dataset_v1"
    shutil.copytree(out["dataset"], out["dataset_v1"])
    _as_version_1(out["dataset_v1"], rig)
    (out["dataset_v1"] / "rig" / "rig.yaml").unlink()
    out["release"] = build_tree(base / "release", n_frames=1)
    out["bundle"] = base / "bundle"
    out["bundle"].mkdir()
    (out["bundle"] / configs.CONFIG_FILE).write_text(json.dumps(configs.run_config_document(
        {"seed": 0, "steps": 10}, get_preset("G16VV-cpu"), [0.5, 1.0, 2.0, 100.0], "paper-train")))
    (out["bundle"] / bundles.PROVENANCE_FILE).write_text(json.dumps({
        "trained_on": "2 rendered scenes",
        "data": [{"role": "mix-0", "cameras": 3, "fov_deg": [190.0, 200.0], "lens": "ds",
                  "models": ["ds"], "spacing_m": [0.2, 0.4]},
                 {"role": "mix-1", "cameras": 4, "fov_deg": [180.0], "lens": "eucm",
                  "spacing_m": [0.3, 0.5]}]}))
    return out


def _read_rig(folder):
    return load_rig(folder / "rig.yaml")


def _read_v2(folder):
    return DatasetReader(folder)


def _read_release(folder):
    return ReleaseDatasetReader(folder, pano=SMALL_LABEL_PANO)


def _check_release(reader):
    check_rig(reader.rig)
    if len(reader):
        sample = reader[0]
        _finite(sample["pano_distance"], "panorama distances")


def _read_and_check_dataset(folder):
    result = check_mod.check_dataset(folder)
    reader = DatasetReader(folder, allow_partial=True, skip_bad=True)
    return result, reader


def _check_checked(pair):
    result, reader = pair
    assert all(isinstance(p, str) for p in result.problems)
    check_dataset_reader(reader)


@functools.lru_cache(maxsize=None)
def _test_rig():
    return tiny_rig()


def _read_provenance(folder):
    prov = bundles.read_provenance(folder)
    return prov, envelope.training_envelope(prov), envelope.envelope_note(_test_rig(), prov,
                                                                          "G16VV-cpu")


def _check_provenance(triple):
    prov, env, note = triple
    assert isinstance(prov, dict)
    if env is not None:
        for field in ("cameras", "fov_deg", "spacing_m"):
            value = getattr(env, field)
            assert value is None or (len(value) == 2 and all(
                isinstance(v, (int, float)) and math.isfinite(v) for v in value)), (field, value)
        assert env.models is None or all(isinstance(m, str) for m in env.models)
    assert note is None or (isinstance(note, str) and "\n" not in note)


def _check_run_config(run):
    assert isinstance(run, configs.RunConfig)
    c = np.asarray(run.candidates, np.float64)
    assert c.ndim == 1 and c.size >= 1 and np.all(np.isfinite(c)) and np.all(c > 0), c
    assert isinstance(run.train, dict) and isinstance(run.rig, str)


# (id, folder key, damaged file, its kind, reader, check)
DOCUMENTS = [
    ("rig_yaml", "rig", "rig.yaml", "yaml", _read_rig, check_rig),
    ("kalibr", "kalibr", "camchain.yaml", "yaml", lambda f: load_rig(f / "camchain.yaml"),
     check_rig),
    ("kalibr_frame_1", "kalibr", "camchain.yaml", "yaml",
     lambda f: load_rig(f / "camchain.yaml", frame_camera=1), check_rig),
    ("basalt", "basalt", "calibration.json", "json",
     lambda f: load_rig(f / "calibration.json"), check_rig),
    ("manifest", "dataset", fmt.MANIFEST, "json", _read_v2, check_dataset_reader),
    ("metadata", "dataset", fmt.METADATA, "json", _read_v2, check_dataset_reader),
    ("dataset_rig", "dataset", fmt.RIG_FILE, "yaml", _read_v2, check_dataset_reader),
    ("file_list", "dataset", f"{fmt.trajectory_name(0)}/{fmt.FILE_LIST}", "text",
     _read_and_check_dataset, _check_checked),
    ("v1_metadata", "dataset_v1", fmt.METADATA, "json", _read_v2, check_dataset_reader),
    ("v1_frame_graph", "dataset_v1", fmt.FRAME_GRAPH, "json", _read_v2, check_dataset_reader),
    ("release_manifest", "release", "manifest.json", "json", _read_release, _check_release),
    ("release_metadata", "release", "metadata.json", "json", _read_release, _check_release),
    ("release_frame_graph", "release", "frame_graph.json", "json", _read_release,
     _check_release),
    ("release_masks", "release", "masks.json", "json", _read_release, _check_release),
    ("release_partitions", "release", "data_partitions.json", "json", _read_release,
     _check_release),
    ("release_trajectory", "release", "EnvA/P000/meta.json", "json", _read_release,
     _check_release),
    ("release_file_list", "release", "EnvA/P000/selected.csv", "text", _read_release,
     _check_release),
    ("provenance", "bundle", bundles.PROVENANCE_FILE, "json", _read_provenance,
     _check_provenance),
    ("run_config", "bundle", configs.CONFIG_FILE, "json", configs.read_run_config,
     _check_run_config),
]


@pytest.mark.parametrize("doc_id,key,name,kind,read,check", DOCUMENTS,
                         ids=[d[0] for d in DOCUMENTS])
def test_damaged_document_gives_one_clear_error_or_a_valid_object(folders, doc_id, key, name,
                                                                   kind, read, check):
    folder = folders[key]
    target = folder / name
    original = target.read_bytes()
    check(read(folder))          # the undamaged document reads, and passes the check
    # An error may name the damaged file or, for a document read through another one (a rig
    # mask, a trajectory's file list, the dataset folder itself), the folder it lives in.
    names = (target.name, str(folder))

    @settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
    @given(st.data())
    def one(data):
        target.write_bytes(damaged(original, kind, data.draw))
        try:
            clear_or_valid(lambda: read(folder), check, names)
        finally:
            target.write_bytes(original)

    one()
