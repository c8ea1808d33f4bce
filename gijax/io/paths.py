"""Checks on output paths, so that a wrong kind of path fails with one clear line up front.

A file where a folder is wanted (or the reverse) otherwise surfaces as an OSError from deep
inside a writer, after the work that produced the output, and sometimes after temporary files
were made.
"""

from __future__ import annotations

import os
from pathlib import Path


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
