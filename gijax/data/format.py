"""The on-disk dataset format: layout, JSON documents, the rig, CSV file lists.

Layout (see docs/data.md for an example tree)::

    ROOT/
      manifest.json        format name and version, the other documents, the trajectories
      metadata.json        panorama, distance range, sky value, encodings
      rig/rig.yaml         the rig: a gijax rig file (cameras, poses, panorama frame, occluder)
      rig/rig_<cam>_mask.png  the rig's static self-occlusion masks (when the rig has them)
      traj_0000/files.csv  one row per frame, one column per file (paths relative to traj_0000/)
      traj_0000/<cam>/rgb/000000.png, <cam>/distance/000000.png, <cam>/mask/000000.png
      traj_0000/pano/distance/000000.png

The rig is stored once, in ``rig/rig.yaml`` (:mod:`gijax.io.rigfile`), and round-trips
bit-exactly (every float32 leaf is written as the shortest decimal that reads back to the same
float32). Datasets of format version 1 also described it in ``metadata.json`` (cameras,
occluder) and ``frame_graph.json`` (poses); they are still read, from those documents, and when
they hold ``rig/rig.yaml`` too the two copies must agree exactly.

Trajectory CSVs are the commit record: a sample exists once its row is in a CSV listed by the
manifest, and both are replaced atomically after all of the sample's files exist.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from gijax.checks import MISSING, bad_document_field, kind_name, kind_of
from gijax.geometry import cameras as cam_lib
from gijax.geometry.occluder import FAR, Cylinder
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import Rig
from gijax.io.masks import read_mask
from gijax.io.text import read_text

FORMAT_NAME = "gijax-multi-fisheye"
FORMAT_VERSION = 2
# Version 1 described the rig in metadata.json and frame_graph.json (and, later, rig/rig.yaml).
FORMAT_VERSIONS = (1, 2)
MANIFEST = "manifest.json"
METADATA = "metadata.json"
FRAME_GRAPH = "frame_graph.json"
FILE_LIST = "files.csv"
RIG_FOLDER = "rig"
RIG_FILE = f"{RIG_FOLDER}/rig.yaml"
PANO_FRAME = "pano"
RIG_FRAME = "rig"
DEFAULT_TRAJECTORY_SIZE = 1000
DEFAULT_DISTANCE_RANGE = (0.5, 100.0)
# The column kinds of a file list, per camera; the panorama has one distance column.
CAMERA_KINDS = ("rgb", "distance", "mask")


# ---------------------------------------------------------------------------- JSON helpers

def inside(root: Path, base: Path, name: str, where: str) -> Path:
    """``base / name`` when it names a file inside the dataset folder ``root``; ValueError
    naming ``where`` otherwise (an absolute path, or ``..`` leading out of the folder): a
    dataset's documents may only point at its own files."""
    if not isinstance(name, str) or not name or "\0" in name:
        raise ValueError(f"{where}: expected a file name inside the dataset, found {name!r}")
    if os.path.isabs(name):
        raise ValueError(f"{where}: {name!r} is an absolute path; a dataset names its files "
                         f"relative to its folder")
    path = Path(base) / name
    top = Path(root).resolve()
    full = path.resolve()
    if full != top and top not in full.parents:
        raise ValueError(f"{where}: {name!r} leads outside the dataset folder {root}")
    return path


def load_json(path: str | os.PathLike, what: str) -> dict:
    """Read a JSON object; FileNotFoundError / ValueError name the file and the position."""
    path = Path(path)
    try:
        text = read_text(path, what)
    except FileNotFoundError:
        raise FileNotFoundError(f"missing {what} {path}") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"malformed {what} {path}: {exc.msg} at line {exc.lineno} column "
                         f"{exc.colno}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"malformed {what} {path}: expected a JSON object, found "
                         f"{type(doc).__name__}")
    return doc


def document_field(doc: dict, key: str, path, kind: type | tuple = object) -> Any:
    """``doc[key]``, raising a ValueError naming the file and the field when absent or mistyped
    (or when ``doc`` is no JSON object)."""
    expected = "present" if kind is object else kind_name(kind)
    if not isinstance(doc, dict):
        raise bad_document_field(path, key, f"{expected} in a JSON object", kind_of(doc))
    if key not in doc:
        raise bad_document_field(path, key, expected, MISSING)
    value = doc[key]
    if not isinstance(value, kind):
        raise bad_document_field(path, key, expected, kind_of(value))
    return value


def dumps(doc: dict) -> bytes:
    """Deterministic JSON bytes (so a resumed run rewrites identical documents)."""
    return (json.dumps(doc, indent=2, sort_keys=False) + "\n").encode("utf-8")


# ---------------------------------------------------------------------------- rig <-> JSON

def camera_from_json(doc: dict, path) -> Any:
    """A camera of a format-version-1 ``metadata.json``, checked as every calibration is
    (:mod:`gijax.io.parsing`: finite intrinsics, positive focal lengths, a bounded positive
    image size, a field of view in (0, 360] degrees)."""
    from gijax.io.parsing import Where, checked_camera, floats, resolution

    where = Where(Path(str(path)), doc.get("name") if isinstance(doc, dict) else None)
    model = document_field(doc, "model", path, str)
    if model not in cam_lib.CAMERA_MODELS:
        raise ValueError(f"{path}: camera {doc.get('name')!r} has unknown model {model!r}; "
                         f"expected one of {sorted(cam_lib.CAMERA_MODELS)}")
    cls = cam_lib.CAMERA_MODELS[model]
    intr = document_field(doc, "intrinsics", path, dict)
    missing = [k for k in cls.PARAMS if k not in intr]
    if missing:
        raise ValueError(f"{path}: camera {doc.get('name')!r} is missing intrinsics {missing}")
    params = {k: float(floats(intr[k], 1, f"intrinsics.{k}", where, "one finite number")[0])
              for k in cls.PARAMS}
    fov_deg = (math.degrees(float(floats(doc["fov_rad"], 1, "fov_rad", where,
                                         "one number of radians")[0]))
               if "fov_rad" in doc else document_field(doc, "fov_deg", path, (int, float)))
    size = resolution([document_field(doc, "width", path, int),
                       document_field(doc, "height", path, int)], where)
    return checked_camera(model, params, size, fov_deg, where)


def metadata_doc(pano: Panorama, distance_range=DEFAULT_DISTANCE_RANGE,
                 sky_distance: float = FAR) -> dict:
    """metadata.json for a ground-truth panorama (the rig is ``rig/rig.yaml``)."""
    return {
        "panorama": {"height": pano.height, "width": pano.width, "lat_min_rad": pano.lat_min,
                     "lat_max_rad": pano.lat_max, "lat_min_deg": math.degrees(pano.lat_min),
                     "lat_max_deg": math.degrees(pano.lat_max)},
        "distance_range": [float(distance_range[0]), float(distance_range[1])],
        "sky_distance": float(sky_distance),
        "encodings": {
            "rgb": "8-bit 3-channel PNG, RGB (stored in OpenCV's BGR channel order)",
            "distance": "float32 metres, little-endian bytes packed into an 8-bit 4-channel PNG",
            "mask": "8-bit 1-channel PNG, 255 = valid (sees the world), 0 = invalid",
        },
    }


def check_names(names) -> None:
    if len(set(names)) != len(names):
        raise ValueError(f"camera names must be unique; found {list(names)}")
    for n in names:
        if not n or n in (RIG_FRAME, PANO_FRAME) or any(ch in n for ch in "/\\,. "):
            raise ValueError(f"camera name {n!r} cannot name files: use letters, digits, '_' "
                             f"or '-', and not {RIG_FRAME!r} or {PANO_FRAME!r}")


def rig_from_docs(root: Path, meta: dict, graph: dict) -> Rig:
    """The rig of a format-version-1 dataset, from its metadata.json, frame_graph.json and the
    rig mask PNGs."""
    from gijax.io.parsing import Where, check_rotation, floats
    meta_path, graph_path = root / METADATA, root / FRAME_GRAPH
    cam_docs = document_field(meta, "cameras", meta_path, list)
    if not cam_docs:
        raise ValueError(f"{meta_path}: field 'cameras' is empty")
    frames = document_field(graph, "frames", graph_path, dict)
    cams, rots, trans, masks, names = [], [], [], [], []
    for k, doc in enumerate(cam_docs):
        where = f"{meta_path} cameras[{k}]"
        name = document_field(doc, "name", where, str)
        cam = camera_from_json(doc, where)
        if name not in frames:
            raise ValueError(f"{graph_path}: no frame for camera {name!r}")
        pose = frames[name]
        # The pose is checked as a rig file's is: finite, and a proper rotation.
        at = Where(graph_path, name)
        rot = check_rotation(floats(document_field(pose, "rotation", f"{graph_path} frame {name!r}",
                                            list), 9, "rotation", at,
                                    "a 3x3 rotation matrix").reshape(3, 3), "rotation", at)
        t = floats(document_field(pose, "translation", f"{graph_path} frame {name!r}", list), 3,
                   "translation", at, "3 finite numbers in metres")
        mask_file = doc.get("mask")
        mask = None
        if mask_file:
            mask = jnp.asarray(read_mask(inside(root, root, mask_file, f"{where} field 'mask'"),
                                         (cam.height, cam.width), f"rig mask of camera {name!r}"))
        cams.append(cam)
        rots.append(rot)
        trans.append(t)
        masks.append(mask)
        names.append(name)
    try:
        check_names(names)
    except ValueError as exc:
        raise ValueError(f"{meta_path}: {exc}") from None
    pano_pose = frames.get(PANO_FRAME, {"translation": [0.0, 0.0, 0.0]})
    at = Where(graph_path, PANO_FRAME)
    if not isinstance(pano_pose, dict):
        raise at.error(PANO_FRAME, "a frame object with rotation and translation", pano_pose)
    reference = floats(pano_pose.get("translation", [0.0, 0.0, 0.0]), 3, "translation", at,
                       "3 finite numbers in metres").astype(np.float32)
    pano_rot = check_rotation(floats(pano_pose.get("rotation", np.eye(3).tolist()), 9,
                                     "rotation", at, "a 3x3 rotation matrix").reshape(3, 3),
                              "rotation", at)
    occ_doc = meta.get("occluder")
    occ = None
    if occ_doc:
        at = Where(meta_path)
        occ = Cylinder(*(jnp.asarray(floats(document_field(occ_doc, f, f"{meta_path} occluder",
                                                    (int, float)), 1, f"occluder.{f}", at,
                                            "one number in metres")[0], jnp.float32)
                         for f in ("x", "y", "radius", "z_min", "z_max")))
    return Rig(tuple(cams), jnp.asarray(np.stack(rots)), jnp.asarray(np.stack(trans)),
               jnp.asarray(reference), tuple(masks), occ, tuple(names),
               jnp.asarray(pano_rot, jnp.float32))


def _number(value, key: str, path) -> float:
    """``value`` of field ``key`` as a float, finite in float32 (labels are float32);
    ValueError naming the file and the field otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            abs(value) <= np.finfo(np.float32).max):
        raise bad_document_field(path, key, "a finite number", value)
    return float(value)


def pano_from_metadata(meta: dict, path) -> Panorama:
    """The ground-truth panorama of metadata.json: a bounded positive size and latitudes
    -90 <= lat_min < lat_max <= 90 degrees."""
    from gijax.io.bounds import check_size

    doc = document_field(meta, "panorama", path, dict)
    height = document_field(doc, "height", path, int)
    width = document_field(doc, "width", path, int)
    if isinstance(height, bool) or isinstance(width, bool):
        raise ValueError(f"{path}: field 'panorama': height and width must be integers; found "
                         f"{height!r}, {width!r}")
    try:
        check_size("panorama", width, height, 4)
    except ValueError as exc:
        raise ValueError(f"{path}: field 'panorama': {exc}") from None
    lat_min = _number(doc.get("lat_min_rad", -math.pi / 2), "lat_min_rad", path)
    lat_max = _number(doc.get("lat_max_rad", 0.0), "lat_max_rad", path)
    if not -math.pi / 2 - 1e-6 <= lat_min < lat_max <= math.pi / 2 + 1e-6:
        raise ValueError(f"{path}: field 'panorama': latitudes must satisfy -pi/2 <= "
                         f"lat_min_rad < lat_max_rad <= pi/2; found {lat_min!r}, {lat_max!r}")
    return Panorama(int(height), int(width), lat_min, lat_max)


def distance_settings(meta: dict, path) -> tuple[tuple[float, float], float]:
    """``(distance_range, sky_distance)`` of metadata.json (defaults when absent), checked:
    0 < near < far and a positive sky distance, all finite."""
    value = meta.get("distance_range", DEFAULT_DISTANCE_RANGE)
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ValueError(f"{path}: field 'distance_range' must be [near, far] in metres; found "
                         f"{value!r}")
    near, far = (_number(v, "distance_range", path) for v in value)
    if not 0.0 < near < far:
        raise ValueError(f"{path}: field 'distance_range' must satisfy 0 < near < far; found "
                         f"{list(value)!r}")
    sky = _number(meta.get("sky_distance", FAR), "sky_distance", path)
    if sky <= 0.0:
        raise ValueError(f"{path}: field 'sky_distance' must be positive; found {sky!r}")
    return (near, far), sky


# ---------------------------------------------------------------------------- file lists

def file_columns(names) -> list[str]:
    """CSV header: frame, seed, <cam>_rgb, <cam>_distance, <cam>_mask per camera, pano_distance."""
    cols = ["frame", "seed"]
    for n in names:
        cols += [f"{n}_{kind}" for kind in CAMERA_KINDS]
    return cols + [f"{PANO_FRAME}_distance"]


def sample_files(names, frame: int) -> dict[str, str]:
    """Column -> path relative to the trajectory folder for one frame."""
    files = {f"{n}_{kind}": f"{n}/{kind}/{frame:06d}.png" for n in names for kind in CAMERA_KINDS}
    files[f"{PANO_FRAME}_distance"] = f"{PANO_FRAME}/distance/{frame:06d}.png"
    return files


def trajectory_name(index: int) -> str:
    return f"traj_{index:04d}"


def csv_records(path: Path, required) -> list[tuple[int, dict[str, str]]]:
    """``(line number, {column: field})`` for every non-empty row of the CSV file list
    ``path``, whose header must hold every column in ``required``. Errors name the file and the
    line: a missing file, no header, missing columns, a row with the wrong field count."""
    try:
        text = read_text(path, "file list")
    except FileNotFoundError:
        raise FileNotFoundError(f"missing file list {path}") from None
    reader = csv.reader(io.StringIO(text))
    try:
        header = next(reader, None)
        if header is None:
            raise ValueError(f"{path}: empty file list (no header row)")
        missing = [c for c in required if c not in header]
        if missing:
            raise ValueError(f"{path} line 1: header lacks column(s) {missing}; found {header}")
        records = []
        for fields in reader:
            if not fields:
                continue
            if len(fields) != len(header):
                raise ValueError(f"{path} line {reader.line_num}: expected {len(header)} "
                                 f"fields, found {len(fields)}")
            records.append((reader.line_num, dict(zip(header, fields))))
    except csv.Error as exc:       # a stray quote or carriage return inside a field
        raise ValueError(f"{path} line {reader.line_num}: not a CSV row ({exc})") from None
    return records


def read_file_list(path: Path, names) -> list[dict[str, str]]:
    """Parse a trajectory CSV; every row must have every required column filled.

    ``<cam>_mask`` and ``seed`` columns are optional (data without per-frame masks use the
    rig's masks). Errors name the file and the line.
    """
    required = ["frame"] + [f"{n}_{k}" for n in names for k in ("rgb", "distance")] + \
        [f"{PANO_FRAME}_distance"]
    rows = []
    for line_no, row in csv_records(path, required):
        for c in required:
            if not row[c]:
                raise ValueError(f"{path} line {line_no}: empty field {c!r}")
        try:
            int(row["frame"])
            if row.get("seed"):
                int(row["seed"])
        except ValueError:
            raise ValueError(f"{path} line {line_no}: frame and seed must be integers; found "
                             f"frame={row['frame']!r} seed={row.get('seed')!r}") from None
        row["_line"] = str(line_no)
        rows.append(row)
    return rows


def file_list_bytes(names, rows: list[dict[str, str]]) -> bytes:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    cols = file_columns(names)
    writer.writerow(cols)
    for row in rows:
        writer.writerow([row.get(c, "") for c in cols])
    return buf.getvalue().encode("utf-8")


def manifest_doc(trajectories: list[str], trajectory_size: int, generator: dict | None,
                 requested: int | None = None) -> dict:
    """``requested``: the sample count the dataset was asked to hold (recorded before the
    first of them is written, so an interrupted writer leaves a dataset that knows it is
    incomplete); None when unknown."""
    doc = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "metadata": METADATA,
        "rig": RIG_FILE,
        "trajectory_size": int(trajectory_size),
        "trajectories": [{"name": t, "file_list": f"{t}/{FILE_LIST}"} for t in trajectories],
        "generator": generator,
    }
    if requested is not None:
        doc["requested_samples"] = int(requested)
    return doc


def requested_samples(manifest: dict, path) -> int | None:
    """The manifest's ``requested_samples`` (None when absent), checked."""
    value = manifest.get("requested_samples")
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{path}: field 'requested_samples' must be a count >= 0; found "
                         f"{value!r}")
    return value


def read_manifest(root: Path) -> dict:
    """Load and check manifest.json (fields and types), naming the file on every error."""
    path = root / MANIFEST
    doc = load_json(path, "manifest")
    trajs = document_field(doc, "trajectories", path, list)
    for k, t in enumerate(trajs):
        if not isinstance(t, dict):
            raise ValueError(f"{path}: trajectories[{k}] must be an object; found "
                             f"{type(t).__name__}")
        document_field(t, "name", f"{path} trajectories[{k}]", str)
        document_field(t, "file_list", f"{path} trajectories[{k}]", str)
    document_field(doc, "metadata", path, str)
    version = manifest_version(doc, path)
    if version == 1:
        document_field(doc, "frame_graph", path, str)
        if "rig" in doc:
            document_field(doc, "rig", path, str)
    else:
        document_field(doc, "rig", path, str)
    return doc


def manifest_version(manifest: dict, path) -> int:
    """The manifest's format version, checked (1 when absent: the first datasets had none)."""
    version = manifest.get("version", 1)
    if isinstance(version, bool) or version not in FORMAT_VERSIONS:
        raise ValueError(f"{path}: format version {version!r} is not one this gijax reads "
                         f"({', '.join(map(str, FORMAT_VERSIONS))})")
    return int(version)


# ---------------------------------------------------------------------------- the rig

def _same(a, b) -> bool:
    a, b = np.asarray(a, np.float32), np.asarray(b, np.float32)
    return a.shape == b.shape and bool(np.array_equal(a, b))


def rig_differences(a: Rig, b: Rig) -> list[str]:
    """What differs between two rigs, compared float32-exactly (empty when they are the same):
    names, camera models, sizes, intrinsics and fields of view, poses, panorama centre and
    orientation (None is the identity), occluder and masks (None and all-valid differ)."""
    if a.names != b.names:
        return [f"camera names {list(a.names)} vs {list(b.names)}"]
    found = []
    for name, ca, cb, ma, mb in zip(a.names, a.cameras, b.cameras, a.masks, b.masks):
        if (type(ca), ca.width, ca.height) != (type(cb), cb.width, cb.height):
            found.append(f"camera {name!r} model or size")
            continue
        params = [k for k in (*ca.PARAMS, "fov") if not _same(getattr(ca, k), getattr(cb, k))]
        if params:
            found.append(f"camera {name!r} intrinsics {params}")
        if (ma is None) != (mb is None) or (ma is not None and not _same(ma, mb)):
            found.append(f"camera {name!r} mask")
    for field in ("rotations", "translations", "reference"):
        if not _same(getattr(a, field), getattr(b, field)):
            found.append(field)
    rot_a, rot_b = (np.eye(3) if r is None else r for r in (a.panorama_rotation,
                                                             b.panorama_rotation))
    if not _same(rot_a, rot_b):
        found.append("panorama_rotation")
    occ = ("x", "y", "radius", "z_min", "z_max")
    if (a.occluder is None) != (b.occluder is None) or (
            a.occluder is not None
            and not all(_same(getattr(a.occluder, f), getattr(b.occluder, f)) for f in occ)):
        found.append("occluder")
    return found


def read_rig(root: Path, manifest: dict, metadata: dict) -> Rig:
    """The rig of the dataset at ``root``: ``rig/rig.yaml`` (the file the manifest's ``rig``
    field names). A version-1 dataset's rig comes from metadata.json and frame_graph.json; when
    it holds a rig file too, a copy that differs is refused in one line naming both files and
    what differs."""
    from gijax.io.rigfile import load_rig

    path = root / MANIFEST
    rig_path = None
    if "rig" in manifest:
        rig_path = inside(root, root, manifest["rig"], f"{path} field 'rig'")
    if manifest_version(manifest, path) >= 2:
        if not rig_path.is_file():
            raise FileNotFoundError(f"missing rig file {rig_path} (named by {path})")
        return load_rig(rig_path)
    graph_path = inside(root, root, manifest["frame_graph"], f"{path} field 'frame_graph'")
    rig = rig_from_docs(root, metadata, load_json(graph_path, "frame graph"))
    if rig_path is not None and rig_path.is_file():
        diff = rig_differences(rig, load_rig(rig_path))
        if diff:
            raise ValueError(f"{root}: the rig in {METADATA} and {graph_path.name} differs from "
                             f"{rig_path} ({'; '.join(diff)}); the dataset's two copies of its "
                             f"rig disagree, so neither can be trusted")
    return rig
