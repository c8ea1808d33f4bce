"""Output paths: checks that make a wrong kind of path fail with one clear line up front, and
the atomic write every output file goes through.

A file where a folder is wanted (or the reverse) otherwise surfaces as an OSError from deep
inside a writer, after the work that produced the output, and sometimes after temporary files
were made.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` under a temporary name in ``path``'s folder, then rename it over ``path``:
    a reader never sees a half-written file, and a failed write leaves no temporary behind."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o644)  # mkstemp makes files private; outputs are meant to be read
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def _blocking_parent(path: Path) -> Path | None:
    """The nearest existing ancestor of ``path`` when it is not a folder (else None)."""
    for parent in path.parents:
        if parent.exists():
            return None if parent.is_dir() else parent
    return None


def check_output_dir(path: str | os.PathLike, option: str = "--out") -> Path:
    """``path`` is a folder or can be created as one; ValueError naming the problem if not."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{option} {path} is an existing file, not a folder; name a folder")
    blocker = _blocking_parent(path)
    if blocker is not None:
        raise ValueError(f"{option} {path}: {blocker} is a file, so no folder can be made "
                         f"inside it")
    return path


def check_output_file(path: str | os.PathLike, option: str = "--out") -> Path:
    """``path`` is a file or can be created as one; ValueError naming the problem if not."""
    path = Path(path)
    if path.is_dir() or str(path).endswith(os.sep):
        raise ValueError(f"{option} {path} is a folder; name a file (e.g. {path / 'out.json'})")
    blocker = _blocking_parent(path)
    if blocker is not None:
        raise ValueError(f"{option} {path}: {blocker} is a file, not a folder")
    return path


__all__ = ["check_output_dir", "check_output_file"]
