"""Read a dataset folder (layout in :mod:`gijax.data.format`) sample by sample.

Every problem raises an error that names the file and, for sample files, the CSV file and line
that point at it: a missing or malformed manifest, metadata or file list, a row whose file is
missing, a truncated or corrupt PNG, a wrong image size or channel count, non-finite distances.
Bad rows are dropped only with ``skip_bad=True``; they are then counted in ``reader.skipped``
and reported by :meth:`DatasetReader.report` (and a warning when the reader opens).

A dataset whose manifest requests more samples than its file lists hold (its writer was
interrupted, or is still writing) is refused unless ``allow_partial=True``, which warns instead.
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np

from gijax.data import format as fmt
from gijax.data import pngio
from gijax.io.lock import describe_holder, holder_of
from gijax.io.masks import read_mask

VERIFY_MODES = ("none", "exists", "full")


@dataclasses.dataclass(frozen=True)
class Skipped:
    """A row dropped under ``skip_bad=True``: where it is and why."""

    file_list: str
    line: int
    reason: str


class RowReader:
    """Random access by sample index for a reader holding ``_rows`` (one per sample),
    ``_load(row)`` and ``rig``: every dataset layout's reader shares it."""

    def __getitem__(self, index: int) -> dict:
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"sample index {index} out of range for {n} samples")
        index = index % n
        sample = self._load(self._rows[index])
        sample["rig"] = self.rig
        sample["index"] = index
        return sample


class DatasetReader(RowReader):
    """Random access to a dataset's samples.

    Args:
      root: dataset folder (the one holding manifest.json).
      skip_bad: drop rows that fail verification instead of raising; they are counted in
        ``skipped`` and reported.
      verify: what to check for every row when opening: ``"none"`` (only the CSV structure),
        ``"exists"`` (every file exists, the default) or ``"full"`` (every file decodes with
        the right size and channels and finite distances; slow on large data). Errors found
        later by ``__getitem__`` always raise.
      allow_partial: accept a dataset holding fewer samples than its manifest requests (with
        a warning) instead of raising ValueError.

    ``reader[i]`` returns a dict: ``images`` uint8 (N, h, w, 3) RGB, ``distances`` float32
    (N, h, w) metres, ``masks`` uint8 (N, h, w) 1 = valid, ``pano_distance`` float32 (H, W)
    metres, ``rig``, and ``index``, ``trajectory``, ``frame``, ``seed`` (None when unknown).
    Cameras of different sizes come back as lists instead of stacked arrays.
    """

    def __init__(self, root, skip_bad: bool = False, verify: str = "exists",
                 allow_partial: bool = False):
        if verify not in VERIFY_MODES:
            raise ValueError(f"verify must be one of {VERIFY_MODES}; found {verify!r}")
        self.root = Path(root)
        if not self.root.is_dir():
            raise FileNotFoundError(f"dataset folder {self.root} does not exist")
        self.manifest = fmt.read_manifest(self.root)
        where = f"{self.root / fmt.MANIFEST}"
        self.metadata = fmt.load_json(fmt.inside(self.root, self.root, self.manifest["metadata"],
                                                 f"{where} field 'metadata'"), "metadata")
        self.rig = fmt.read_rig(self.root, self.manifest, self.metadata)
        self.pano = fmt.pano_from_metadata(self.metadata, self.root / fmt.METADATA)
        self.names = list(self.rig.names)
        self.distance_range, self.sky_distance = fmt.distance_settings(
            self.metadata, self.root / fmt.METADATA)
        self._rig_masks = [None if m is None else np.asarray(m > 0.5, np.uint8)
                           for m in self.rig.masks]
        self.skip_bad = skip_bad
        self.skipped: list[Skipped] = []
        self._rows: list[tuple[str, Path, dict]] = []
        for t in self.manifest["trajectories"]:
            csv_path = fmt.inside(self.root, self.root, t["file_list"],
                                  f"{where} trajectory {t.get('name')!r} field 'file_list'")
            for row in fmt.read_file_list(csv_path, self.names):
                self._rows.append((t["name"], csv_path, row))
        self.requested = fmt.requested_samples(self.manifest, self.root / fmt.MANIFEST)
        self.complete = self.requested is None or len(self._rows) >= self.requested
        if not self.complete:
            writer = holder_of(self.root)
            how = (f"it is being written now by {describe_holder(writer)}" if writer else
                   "its writer stopped early: re-run the command that made it to finish it")
            msg = (f"dataset {self.root} is incomplete: {len(self._rows)} of the "
                   f"{self.requested} samples its manifest requests ({how}); to use it as it "
                   f"is, pass --allow-partial (allow_partial=True)")
            if not allow_partial:
                raise ValueError(msg)
            warnings.warn(msg, stacklevel=2)
        if verify != "none":
            kept = []
            for entry in self._rows:
                try:
                    self._check_row(entry, full=verify == "full")
                except (FileNotFoundError, ValueError) as exc:
                    if not skip_bad:
                        raise
                    self.skipped.append(Skipped(str(entry[1]), int(entry[2]["_line"]), str(exc)))
                    continue
                kept.append(entry)
            self._rows = kept
        if self.skipped:
            warnings.warn(self.report(), stacklevel=2)

    def __len__(self) -> int:
        return len(self._rows)

    def report(self) -> str:
        """A human-readable summary: samples kept and every skipped row with its reason."""
        lines = [f"{self.root}: {len(self)} samples, {len(self.skipped)} bad row(s) skipped"]
        lines += [f"  {s.file_list} line {s.line}: {s.reason}" for s in self.skipped]
        return "\n".join(lines)

    def location(self, index: int) -> str:
        _, csv_path, row = self._rows[index]
        return f"{csv_path} line {row['_line']}"

    def row_files(self, index: int) -> dict[str, Path]:
        """Column -> file of sample ``index`` (as listed; the files are not opened)."""
        return self._files(self._rows[index])

    def _files(self, entry) -> dict[str, Path]:
        traj, csv_path, row = entry
        folder = csv_path.parent
        return {k: fmt.inside(self.root, folder, v, f"column {k!r}, {csv_path} line {row['_line']}")
                for k, v in row.items() if k not in ("frame", "seed", "_line") and v}

    def _check_row(self, entry, full: bool) -> None:
        if full:
            self._load(entry)
            return
        where = f"{entry[1]} line {entry[2]['_line']}"
        for col, path in self._files(entry).items():
            if not path.is_file():
                raise FileNotFoundError(f"missing file {path} (column {col!r}, {where})")

    def _load(self, entry) -> dict:
        traj, csv_path, row = entry
        files = self._files(entry)
        where = lambda col: f"column {col!r}, {csv_path} line {row['_line']}"
        images, distances, masks = [], [], []
        for c, (name, cam) in enumerate(zip(self.names, self.rig.cameras)):
            hw = (cam.height, cam.width)
            col = f"{name}_rgb"
            images.append(pngio.read_rgb(files[col], hw, where(col)))
            col = f"{name}_distance"
            distances.append(pngio.read_distance(files[col], hw, where(col)))
            col = f"{name}_mask"
            if col in files:
                masks.append(read_mask(files[col], hw, where(col)).astype(np.uint8))
            elif self._rig_masks[c] is not None:
                masks.append(self._rig_masks[c])
            else:
                masks.append(np.ones(hw, np.uint8))
        col = f"{fmt.PANO_FRAME}_distance"
        pano = pngio.read_distance(files[col], self.pano.shape, where(col))
        same = len({(c.height, c.width) for c in self.rig.cameras}) == 1
        stack = np.stack if same else list
        return {"images": stack(images), "distances": stack(distances), "masks": stack(masks),
                "pano_distance": pano, "trajectory": traj, "frame": int(row["frame"]),
                "seed": int(row["seed"]) if row.get("seed") else None}

