"""Output folders that gijax replaces whole: only its own, atomically, recovering after a kill.

A command that writes a folder of results (an inference bundle, a prediction) must neither
destroy what it did not write nor leave a mix of old and new files when it stops half way
(interrupted, disk full). The rules, in one place for every such writer:

* **Only what is ours.** An existing ``--out`` is replaced only when it is empty or holds
  nothing but the file names of its kind and, when the kind has one, its record file (the
  marker that gijax wrote it); never a link, the working folder or a folder above it, or a
  folder that holds one of the command's inputs. Anything else is refused in one line before
  any work (:func:`check_replaceable`).
* **Atomic.** The new folder is assembled under a temporary name beside the old one; the old
  one is renamed aside, the new one renamed into place, the old one removed. A reader sees the
  old folder or the new one, never a mix.
* **Recovered.** A kill between the two renames leaves no folder and the old one aside: the
  next call (under the same lock) puts it back, and removes temporaries that hold only the
  kind's file names (:func:`recover`).
* **One writer.** The lock file sits beside the folder (``.NAME.gijax.lock``), since the folder
  itself is replaced.
"""

from __future__ import annotations

import dataclasses
import os
import secrets
import shutil
from pathlib import Path
from typing import Callable, TypeVar

from gijax.io.lock import FolderLock
from gijax.io.paths import check_output_dir, temporary_folder_beside

T = TypeVar("T")


@dataclasses.dataclass(frozen=True)
class FolderKind:
    """What an output folder of one kind may hold.

    Attributes:
      name: how messages name the folder ('bundle folder', 'prediction folder').
      noun: how they name what it holds ('bundle', 'prediction').
      files: every file name the kind writes (nothing else, no subfolders, no links).
      record: the file that marks a folder as written by gijax (None: the file names decide).
      patterns: further names the kind writes, as shell patterns (``fnmatch``), for files
        whose names vary (a bundle's figures, ``validation_<rig>.png``).
    """

    name: str
    noun: str
    files: frozenset[str]
    record: str | None = None
    patterns: tuple[str, ...] = ()

    def names(self, name: str) -> bool:
        """Whether ``name`` is a file name this kind writes."""
        from fnmatch import fnmatchcase

        return name in self.files or any(fnmatchcase(name, p) for p in self.patterns)

    def holds_only_its_files(self, folder: Path) -> bool:
        """Whether ``folder`` is a real folder holding nothing but regular files of this kind
        (an empty folder does)."""
        return folder.is_dir() and not folder.is_symlink() and all(
            self.names(p.name) and p.is_file() and not p.is_symlink()
            for p in folder.iterdir())

    def owns(self, folder: Path) -> bool:
        """Whether gijax may replace ``folder``: empty, or only this kind's files with its
        record among them."""
        if not self.holds_only_its_files(folder):
            return False
        names = {p.name for p in folder.iterdir()}
        return not names or self.record is None or self.record in names


def check_replaceable(folder: str | os.PathLike, kind: FolderKind, inputs=()) -> Path:
    """``folder`` as a Path when ``kind`` may be written there (a new path, or a folder that
    :meth:`FolderKind.owns`, is not the working folder or above it and holds none of
    ``inputs``); else ValueError, one line naming the problem."""
    folder = check_output_dir(folder, kind.name)
    if not folder.exists() and not folder.is_symlink():
        return folder
    if folder.is_symlink() or not folder.is_dir():
        raise ValueError(f"{kind.name} {folder}: exists and is not a folder gijax wrote (a "
                         f"link or a file); choose a new path")
    where = folder.resolve()
    cwd = Path.cwd().resolve()
    if cwd == where or where in cwd.parents:
        raise ValueError(f"{kind.name} {folder}: is the working folder or holds it; the "
                         f"{kind.name} is replaced whole, so choose a new path")
    for item in inputs:
        item = Path(item).resolve()
        if item == where or where in item.parents:
            raise ValueError(f"{kind.name} {folder}: holds the input {item}; choose a new path")
    if not kind.owns(folder):
        others = sorted(p.name for p in folder.iterdir() if not kind.names(p.name))
        if others:
            what = f"it holds {', '.join(others[:3])}{', ...' if len(others) > 3 else ''}"
        elif not kind.holds_only_its_files(folder):
            what = "it holds links or folders"
        else:
            what = f"it has no {kind.record}"
        raise ValueError(f"{kind.name} {folder}: exists and is not a {kind.noun} ({what}); "
                         f"gijax replaces only a {kind.name}, so choose a new path")
    return folder


def lock_file(folder: Path) -> Path:
    """Where the writers of ``folder`` lock it: beside it, as the folder itself is replaced."""
    return folder.parent / f".{folder.name}.gijax.lock"


def recover(folder: Path, kind: FolderKind) -> None:
    """Under the folder's lock: put back a folder that a killed replacement had moved aside,
    and remove the temporaries such a kill left (only ones holding nothing but ``kind``'s
    files)."""
    aside = sorted(folder.parent.glob(f".{folder.name}.old-*"))
    if not folder.exists() and not folder.is_symlink() and aside and \
            kind.holds_only_its_files(aside[-1]):
        os.replace(aside[-1], folder)
    for tmp in folder.parent.glob(f".{folder.name}.*"):
        if tmp.is_dir() and not tmp.is_symlink() and kind.holds_only_its_files(tmp):
            shutil.rmtree(tmp)


def replace_folder(folder: str | os.PathLike, kind: FolderKind, write: Callable[[Path], T],
                   inputs=()) -> T:
    """Write a new ``folder`` of ``kind`` with ``write(tmp)`` (which fills the temporary folder
    ``tmp`` plainly; the folder is the unit made atomic) and swap it in; returns what ``write``
    returned. ``folder`` must pass :func:`check_replaceable`; call that before the work that
    produces the contents, so a refusal costs nothing. On any exception (Ctrl-C and a full disk
    included) the temporary folder is removed and an existing folder is left as it was."""
    folder = check_replaceable(folder, kind, inputs)
    folder.parent.mkdir(parents=True, exist_ok=True)
    with FolderLock(folder, kind.noun, lock_file(folder)):
        recover(folder, kind)
        tmp = temporary_folder_beside(folder)
        try:
            result = write(tmp)
            stray = [p.name for p in tmp.iterdir() if not kind.names(p.name)]
            if stray:
                raise RuntimeError(f"{kind.name} writer made files outside its kind: {stray}")
            aside = None
            if folder.exists():
                aside = folder.parent / f".{folder.name}.old-{secrets.token_hex(4)}"
                os.replace(folder, aside)
            os.replace(tmp, folder)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        if aside is not None:
            shutil.rmtree(aside, ignore_errors=True)
    return result


__all__ = ["FolderKind", "check_replaceable", "lock_file", "recover", "replace_folder"]
