"""Reading PNG files exactly as stored, with one clear error for a missing, truncated or
damaged file.

libpng, asked to decode damaged bytes, prints a stray line of its own and may return part of an
image; checking the chunk structure first (every chunk whole, every CRC right, the end chunk
last) turns that into one ValueError naming the file.
"""

from __future__ import annotations

import os
import zlib
from pathlib import Path

import numpy as np

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# Every complete PNG ends with this 12-byte IEND chunk (length 0, type, fixed CRC).
PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def check_png_chunks(data: bytes) -> str | None:
    """What is wrong with the chunk structure of PNG bytes (None when every chunk is whole and
    its CRC matches)."""
    view = memoryview(data)
    pos, n = len(PNG_SIGNATURE), len(data)
    while pos + 12 <= n:
        length = int.from_bytes(view[pos:pos + 4], "big")
        kind = bytes(view[pos + 4:pos + 8]).decode("latin-1")
        end = pos + 12 + length
        if end > n:
            return f"chunk {kind!r} at byte {pos} runs past the end of the file"
        if zlib.crc32(view[pos + 4:end - 4]) != int.from_bytes(view[end - 4:end], "big"):
            return f"CRC mismatch in chunk {kind!r} at byte {pos} (damaged bytes)"
        if kind == "IEND":
            return None if end == n else f"{n - end} bytes after the PNG end chunk"
        pos = end
    return "no PNG end chunk"


def is_png(path: str | os.PathLike) -> bool:
    """Whether the file at ``path`` starts with the PNG signature (False when unreadable)."""
    try:
        with open(path, "rb") as f:
            return f.read(len(PNG_SIGNATURE)) == PNG_SIGNATURE
    except OSError:
        return False


def read_png(path: str | os.PathLike, where: str = "") -> np.ndarray:
    """Decode a PNG file exactly as stored (uint8 or uint16, 1/3/4 channels, OpenCV's BGR
    order; 1-, 2- and 4-bit images come back as 8-bit).

    Raises FileNotFoundError when it is missing and ValueError when it is not a complete PNG
    (a truncated file lacks the final IEND chunk). ``where`` (e.g. the CSV row that names the
    file) is appended to every message.
    """
    import cv2

    path = Path(path)
    suffix = f" ({where})" if where else ""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(f"missing file {path}{suffix}") from None
    except IsADirectoryError:
        raise ValueError(f"{path} is a folder, not a PNG file{suffix}") from None
    if not data.startswith(PNG_SIGNATURE):
        raise ValueError(f"{path} is not a PNG file (bad signature){suffix}")
    if not data.endswith(PNG_IEND):
        raise ValueError(f"{path} is truncated: {len(data)} bytes, no PNG end chunk{suffix}")
    problem = check_png_chunks(data)
    if problem is not None:
        raise ValueError(f"{path} is a corrupt PNG: {problem}{suffix}")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{path} is a corrupt PNG (OpenCV cannot decode it){suffix}")
    return image


__all__ = ["PNG_IEND", "PNG_SIGNATURE", "check_png_chunks", "is_png", "read_png"]
