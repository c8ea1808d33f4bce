"""Which layout a dataset folder holds (gijax's own or the release's) and a reader for it."""

from __future__ import annotations

from pathlib import Path

from gijax.data import format as fmt
from gijax.data.release.layout import MANIFEST, PARTITIONS
from gijax.data.release.reader import ReleaseDatasetReader


def detect_layout(root) -> str:
    """``"gijax"`` or ``"release"`` from the files in ``root``; a clear error when neither."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"dataset folder {root} does not exist")
    manifest = root / MANIFEST
    if not manifest.is_file():
        raise FileNotFoundError(
            f"{root} is not a dataset: missing {MANIFEST} (a gijax dataset has manifest.json "
            f"with format {fmt.FORMAT_NAME!r}; the release layout has manifest.json with "
            f"'camera_models' beside {PARTITIONS})")
    doc = fmt.load_json(manifest, "manifest")
    if doc.get("format") == fmt.FORMAT_NAME or "trajectories" in doc:
        return "gijax"
    if "camera_models" in doc or (root / PARTITIONS).is_file():
        return "release"
    raise ValueError(f"{manifest}: neither a gijax manifest (field 'format' = "
                     f"{fmt.FORMAT_NAME!r}) nor the release's (field 'camera_models'); found "
                     f"fields {sorted(doc)}")


def open_reader(root, split: str = "train", allow_partial: bool = False, **kw):
    """A reader for either layout: :class:`gijax.data.DatasetReader` for gijax's own,
    :class:`ReleaseDatasetReader` (partition ``split``) for the release's.

    ``allow_partial`` concerns gijax datasets only (the release layout records no requested
    sample count); other keywords go to the reader of the detected layout.
    """
    if detect_layout(root) == "release":
        return ReleaseDatasetReader(root, split=split, **kw)
    from gijax.data.reader import DatasetReader

    if allow_partial:
        kw["allow_partial"] = True
    return DatasetReader(root, **kw)
