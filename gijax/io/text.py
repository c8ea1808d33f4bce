"""Text documents read with errors that name the file: every reader of JSON, YAML and CSV
documents opens them here, so a damaged file (cut short, bytes flipped, a binary file in its
place) is refused in one line naming it rather than with a decoder's message that does not."""

from __future__ import annotations

import os
from pathlib import Path


def read_text(path: str | os.PathLike, what: str = "file") -> str:
    """The UTF-8 text of ``path``; ValueError naming the file and the first bad byte when it is
    not UTF-8 text or a folder. A missing file raises FileNotFoundError (the caller's
    wording)."""
    try:
        data = Path(path).read_bytes()
    except IsADirectoryError:
        raise ValueError(f"{path}: expected a {what}, found a folder") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: {what} is not UTF-8 text (byte {exc.start}: "
                         f"{exc.reason}); the file is damaged or of another kind") from None


def one_line(message) -> str:
    """A parser's message (YAML's span several lines) on one line."""
    return " ".join(str(message).split())


__all__ = ["one_line", "read_text"]
