"""Verify every file of a dataset folder: decodes, sizes and channels, value ranges, completeness.

:func:`check_dataset` reads each file a sample lists (RGB, distance and mask PNGs of every
camera and the panorama label) and records every problem with the file and the CSV row that
names it, instead of stopping at the first: a training run then learns about a damaged file
before it starts, not when its loader reaches that sample. It also reports whether the
dataset holds the samples its manifest requests, whether a writer holds it right now, and
files no row lists (left by an interrupted writer; harmless, a resumed writer overwrites them).
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path
from typing import Callable, Optional


from gijax.data import format as fmt
from gijax.data import pngio
from gijax.io.lock import LOCK_FILE, describe_holder, holder_of
from gijax.io.masks import read_mask


@dataclasses.dataclass
class DatasetCheck:
    """What :func:`check_dataset` found."""

    root: Path
    samples: int
    requested: Optional[int]
    files_checked: int = 0
    problems: list = dataclasses.field(default_factory=list)
    notes: list = dataclasses.field(default_factory=list)
    writer: Optional[dict] = None

    @property
    def complete(self) -> bool:
        return self.requested is None or self.samples >= self.requested

    @property
    def ok(self) -> bool:
        """No damaged file and every requested sample present."""
        return not self.problems and self.complete

    def summary(self) -> str:
        of = "" if self.requested is None else f" of {self.requested} requested"
        state = "OK" if not self.problems else f"{len(self.problems)} problem(s)"
        if not self.complete:
            state += ", INCOMPLETE"
        if self.writer:
            state += f", being written by {describe_holder(self.writer)}"
        return (f"{self.root}: {self.samples} samples{of}, {self.files_checked} files checked: "
                f"{state}")


def _check_file(path: Path, column: str, shapes: dict, where: str) -> None:
    name, kind = column.rsplit("_", 1) if "_" in column else (column, "")
    if name not in shapes:
        raise ValueError(f"unknown column {column!r} ({where}): the rig has no camera {name!r}")
    hw = shapes[name]
    if kind == "rgb":
        pngio.read_rgb(path, hw, where)
    elif kind == "distance":
        d = pngio.read_distance(path, hw, where)     # raises on non-finite values
        # 0 marks a label hole (no ground truth there); negative distances are damage.
        if d.size and float(d.min()) < 0.0:
            raise ValueError(f"{path}: distances must be >= 0 m; found minimum {float(d.min())} "
                             f"({where})")
    elif kind == "mask":
        read_mask(path, hw, where)
    else:
        raise ValueError(f"unknown column {column!r} ({where})")


def check_dataset(root, progress: Callable[[int, int], None] | None = None) -> DatasetCheck:
    """Check every file of the dataset at ``root``; ``progress(done, total)`` after each sample.

    Raises (FileNotFoundError / ValueError) only when the dataset cannot be opened at all
    (manifest, metadata, rig file, rig masks or a file list unreadable); problems with
    sample files are collected in the result.
    """
    from gijax.data.reader import DatasetReader

    root = Path(root)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")       # completeness is part of the result instead
        reader = DatasetReader(root, verify="none", allow_partial=True)
    shapes = {n: (c.height, c.width) for n, c in zip(reader.names, reader.rig.cameras)}
    shapes[fmt.PANO_FRAME] = reader.pano.shape
    result = DatasetCheck(root, len(reader), reader.requested, writer=holder_of(root))
    listed = set()
    for i in range(len(reader)):
        where = reader.location(i)
        for column, path in reader.row_files(i).items():
            listed.add(path.resolve())
            result.files_checked += 1
            try:
                _check_file(path, column, shapes, f"column {column!r}, {where}")
            except (FileNotFoundError, ValueError) as exc:
                result.problems.append(str(exc))
        if progress is not None:
            progress(i + 1, len(reader))
    folders = {(root / t["file_list"]).parent for t in reader.manifest["trajectories"]}
    folders |= {p for p in root.glob("traj_*") if p.is_dir()}
    for folder in sorted(folders):
        for path in sorted(folder.rglob("*")) if folder.is_dir() else ():
            if path.is_file() and path.name not in (fmt.FILE_LIST, LOCK_FILE) \
                    and path.resolve() not in listed:
                result.notes.append(f"{path} is listed by no file list row (left by an "
                                    f"interrupted writer; a resumed one overwrites it)")
    if not result.complete:
        result.notes.insert(0, f"{root} holds {result.samples} of the {result.requested} "
                               f"samples its manifest requests")
    return result


def check_with_progress(path, what: str = "dataset", progress: bool = True) -> DatasetCheck:
    """:func:`check_dataset` with a progress bar (on stderr)."""
    from tqdm import tqdm

    bar = tqdm(desc=f"check {what}", unit="sample", disable=not progress, leave=False)

    def update(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)

    try:
        return check_dataset(path, update)
    finally:
        bar.close()


def require_clean(path, what: str, allow_partial: bool, progress: bool = True) -> None:
    """Check a dataset a command is about to use; one-line ValueError on the first problem,
    and when it is incomplete unless ``allow_partial``."""
    result = check_with_progress(path, what, progress)
    if result.problems:
        more = (f" (and {len(result.problems) - 1} more)" if len(result.problems) > 1 else "")
        raise ValueError(f"{what} data {path}: {result.problems[0]}{more}; 'gijax data check "
                         f"{path}' lists every problem, --no-data-check skips this check")
    if not result.complete and not allow_partial:
        raise ValueError(f"{what} data {path} is incomplete: {result.samples} of the "
                         f"{result.requested} samples its manifest requests; finish it by "
                         f"re-running the command that made it, or pass --allow-partial")


__all__ = ["DatasetCheck", "check_dataset", "check_with_progress", "require_clean"]
