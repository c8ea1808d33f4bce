"""The release's file lists: ``data_partitions.json`` names trajectories (folders whose
``meta.json`` selects a CSV) or CSV files directly; each CSV row lists one sample's files."""

from __future__ import annotations

from pathlib import Path

from gijax.data import format as fmt
from gijax.data.release.layout import DIST_SUFFIX, PARTITIONS, RGB_SUFFIX, RIG_KEY, TRAJ_META


def partition_rows(root: Path, split: str, cameras: list[str], rgb_suffix: str = RGB_SUFFIX,
                   dist_suffix: str = DIST_SUFFIX) -> list[dict]:
    """The file entries of partition ``split`` of ``data_partitions.json``, in listed order.

    Each entry: ``csv`` (the file list), ``line`` (its line), ``trajectory`` (``ENV/NAME``),
    ``frame`` (row in its CSV), ``rgb`` (one path per camera), ``label`` (the rig's distance
    image) and ``dist`` (per-camera distance images, or None where the CSV has none).
    """
    path = root / PARTITIONS
    doc = fmt.load_json(path, "data partitions")
    if split not in doc:
        raise ValueError(f"{path}: no partition {split!r}; found {sorted(doc)}")
    part = doc[split]
    if not isinstance(part, dict):
        raise ValueError(f"{path}: partition {split!r} must map environments to lists "
                         f"of trajectories; found {type(part).__name__}")
    rows = []
    for env, names in part.items():
        if not isinstance(names, list):
            raise ValueError(f"{path}: {split}[{env!r}] must be a list; found "
                             f"{type(names).__name__}")
        for name in names:
            where = root / env / str(name)
            if where.is_dir():
                meta_path = where / TRAJ_META
                meta = fmt.load_json(meta_path, "trajectory metadata")
                csv_name = fmt.document_field(meta, "selected_file_list", meta_path, str)
                rows += csv_rows(where / csv_name, where, f"{env}/{name}", cameras, rgb_suffix,
                                 dist_suffix)
            elif str(name).endswith(".csv"):
                rows += csv_rows(where, root, f"{env}/{name}", cameras, rgb_suffix, dist_suffix)
            else:
                raise ValueError(f"{path}: {split}[{env!r}] lists {name!r}, which is "
                                 f"neither a trajectory folder ({where} does not exist) nor "
                                 f"a .csv file")
    return rows


def csv_rows(path: Path, base: Path, trajectory: str, cameras: list[str],
             rgb_suffix: str = RGB_SUFFIX, dist_suffix: str = DIST_SUFFIX) -> list[dict]:
    """The file entries of one CSV file list (paths relative to ``base``)."""
    rgb_cols = [f"{n}{rgb_suffix}" for n in cameras]
    label_col = f"{RIG_KEY}{dist_suffix}"
    records = fmt.csv_records(path, rgb_cols + [label_col])
    dist_cols = [f"{n}{dist_suffix}" for n in cameras]
    has_dist = bool(records) and all(c in records[0][1] for c in dist_cols)
    out = []
    for line, row in records:
        def file(col):
            if not row[col]:
                raise ValueError(f"{path} line {line}: empty field {col!r}")
            # The release splits on backslashes so Windows-written lists work too.
            return base.joinpath(*row[col].replace("\\", "/").split("/"))

        out.append({"csv": path, "line": line, "trajectory": trajectory,
                    "frame": len(out), "rgb": [file(c) for c in rgb_cols],
                    "label": file(label_col),
                    "dist": [file(c) for c in dist_cols] if has_dist else None})
    return out
