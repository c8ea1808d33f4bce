"""Output paths: checks that make a wrong kind of path fail with one clear line up front, and
the atomic write every output file goes through (bytes, text, JSON, NPY, PNG, figures).

A file where a folder is wanted (or the reverse) otherwise surfaces as an OSError from deep
inside a writer, after the work that produced the output, and sometimes after temporary files
were made.

Atomic writes: the content goes to a new temporary file in the destination's folder (the same
file system, so the final ``os.replace`` is a rename), is flushed to disk, and is then renamed
over the destination. A reader sees the old file or the new one, never half of one; a write
that fails removes its temporary and leaves the old file as it was.

The temporary file is created with ``os.open(..., O_CREAT | O_EXCL, 0o666)`` rather than
``tempfile.mkstemp``: mkstemp makes its files 0o600 on purpose, and after the rename that
private mode would be the output's, so nobody else could read a rig file, a prediction or a
dataset. Asking the kernel for 0o666 gives ``0o666 & ~umask`` (or what the folder's default ACL
says, where one is set), exactly like any ordinary ``open``. The umask is thereby honoured
without being read: reading it means ``os.umask(x); os.umask(old)``, which changes it for the
whole process for a moment (a thread creating files in that window gets the wrong mode, and a
lock only orders callers that take it), or parsing ``/proc/self/status``, which is Linux-only.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
from pathlib import Path
from typing import Iterator

# O_EXCL: never reuse (or follow a link at) an existing name; O_CLOEXEC: no child process
# inherits the descriptor; O_BINARY exists only on Windows.
_CREATE_FLAGS = (os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
                 | getattr(os, "O_BINARY", 0))
# File names are limited to 255 bytes; the temporary adds a dot, 8 hex digits and a suffix.
_MAX_NAME_PART = 200


def _create_temporary(path: Path, suffix: str) -> Path:
    """A new, empty file ``.<name>.<random><suffix>`` beside ``path``, mode 0o666 less umask."""
    name = path.name[:_MAX_NAME_PART]
    for _ in range(100):
        tmp = path.with_name(f".{name}.{secrets.token_hex(4)}{suffix}")
        try:
            os.close(os.open(tmp, _CREATE_FLAGS, 0o666))
            return tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"{path.parent}: could not find a free temporary name for {path.name}")


def temporary_folder_beside(path: str | os.PathLike) -> Path:
    """A new, empty folder ``.<name>.<random>`` beside ``path``, mode 0o777 less umask (unlike
    ``tempfile.mkdtemp``'s private 0o700), for writers that assemble a whole folder and rename
    it into place (bundles). The caller renames or removes it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    name = path.name[:_MAX_NAME_PART]
    for _ in range(100):
        folder = path.with_name(f".{name}.{secrets.token_hex(4)}")
        try:
            os.mkdir(folder, 0o777)
            return folder
        except FileExistsError:
            continue
    raise FileExistsError(f"{path.parent}: could not find a free temporary name for {path.name}")


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable; file systems that refuse fsync on a folder (some
    network and FUSE ones) give no stronger promise, so a refusal is not an error."""
    try:
        _fsync(folder)
    except OSError:
        pass


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, suffix: str | None = None,
                fsync: bool = True) -> Iterator[Path]:
    """A temporary path to write ``path``'s content to, renamed over ``path`` when the block ends.

    For writers that need a file name rather than bytes (``cv2.imwrite``, matplotlib's
    ``savefig``, ``onnx.save_model``). The temporary exists (empty) when the block starts, and
    writers keep its mode when they overwrite it. When the block raises, the temporary is
    removed and ``path`` is left as it was.

    Args:
      path: the destination; its folder is created when missing.
      suffix: end of the temporary's name; by default ``.tmp`` plus ``path``'s own extension,
        since some writers choose the format by it (``cv2.imwrite``) or append one when it is
        missing (``np.save``).
      fsync: flush the content and the rename to disk (off only for bulk writers that accept
        losing the last files of a power cut, e.g. datasets not written as durable).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _create_temporary(path, ".tmp" + path.suffix if suffix is None else suffix)
    try:
        yield tmp
        if fsync:
            _fsync(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if fsync:
        _fsync_folder(path.parent)


def write_bytes_atomic(path: str | os.PathLike, data: bytes, *, suffix: str = ".tmp",
                       fsync: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`); returns ``path``."""
    path = Path(path)
    with atomic_path(path, suffix=suffix, fsync=fsync) as tmp:
        tmp.write_bytes(data)
    return path


def write_text_atomic(path: str | os.PathLike, text: str, *, fsync: bool = True) -> Path:
    """Write ``text`` as UTF-8 to ``path`` atomically (see :func:`atomic_path`)."""
    return write_bytes_atomic(path, text.encode("utf-8"), fsync=fsync)


def write_json_atomic(path: str | os.PathLike, obj, *, indent: int | None = 2,
                      fsync: bool = True) -> Path:
    """Write ``obj`` as JSON (``indent``, then a newline) to ``path`` atomically. Non-finite
    floats are written as ``NaN`` / ``Infinity`` as Python's json does; callers that need strict
    JSON convert them first."""
    return write_text_atomic(path, json.dumps(obj, indent=indent) + "\n", fsync=fsync)


def save_npy_atomic(path: str | os.PathLike, array) -> Path:
    """Write ``array`` as an ``.npy`` file to ``path`` atomically (``np.save`` format)."""
    import numpy as np

    path = Path(path)
    # The temporary's name ends in ".npy", so np.save appends no extension of its own.
    with atomic_path(path, suffix=".tmp.npy") as tmp:
        np.save(tmp, np.asarray(array))
    return path


def write_png_atomic(path: str | os.PathLike, image, *, fsync: bool = True) -> Path:
    """Write ``image`` as a PNG file to ``path`` atomically: (H, W) grey or (H, W, 3) RGB, 8- or
    16-bit. ValueError naming the file when OpenCV cannot encode it."""
    import cv2
    import numpy as np

    path = Path(path)
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] == 3:
        image = image[..., ::-1]  # OpenCV writes BGR
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image))
    if not ok:
        raise ValueError(f"{path}: OpenCV could not encode an image of shape {image.shape} and "
                         f"dtype {image.dtype} as PNG")
    return write_bytes_atomic(path, buf.tobytes(), fsync=fsync)


def save_figure_atomic(fig, path: str | os.PathLike, **savefig_kwargs) -> Path:
    """Save a matplotlib figure to ``path`` atomically; ``savefig_kwargs`` go to ``savefig``.
    The format follows ``path``'s extension unless ``format`` says otherwise (the temporary
    keeps the extension)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **savefig_kwargs)
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


__all__ = ["atomic_path", "check_output_dir", "check_output_file", "save_figure_atomic",
           "save_npy_atomic", "temporary_folder_beside", "write_bytes_atomic", "write_json_atomic", "write_png_atomic",
           "write_text_atomic"]
