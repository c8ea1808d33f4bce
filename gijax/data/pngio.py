"""PNG encoding of the dataset's arrays, and atomic file writes.

* RGB images: uint8 (h, w, 3) RGB in memory, an 8-bit 3-channel PNG on disk (OpenCV stores the
  channels as BGR; conversion happens here, so callers only ever see RGB).
* Distances: float32 (h, w) metres, packed bit-exactly into an 8-bit 4-channel PNG: the four
  little-endian bytes of each float32 are the four channels of its pixel (byte 0 = the first
  channel as OpenCV reads it). PNG is lossless, so the round trip is bit-exact, NaN payloads
  and infinities included.
* Masks: uint8 (h, w) in {0, 1} in memory, an 8-bit 1-channel PNG with 0 / 255 on disk (so the
  files are viewable); reading maps any non-zero value to 1.

Every writer goes through :func:`atomic_write_bytes`: the bytes land in a temporary name in
the same folder, then ``os.replace`` renames it, so a file either exists complete or not at all
(:func:`gijax.io.paths.write_bytes_atomic`).
"""

from __future__ import annotations

import os
import zlib
from pathlib import Path

import cv2
import numpy as np

from gijax.io.paths import write_bytes_atomic

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# Every complete PNG ends with this 12-byte IEND chunk (length 0, type, fixed CRC).
PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"
PARTIAL_SUFFIX = ".partial"


def atomic_write_bytes(path: str | os.PathLike, data: bytes, durable: bool = False) -> None:
    """Write ``data`` to ``path`` atomically (fsync first when ``durable``); the temporary's
    name ends in :data:`PARTIAL_SUFFIX`, so the leftovers of a killed writer can be found."""
    write_bytes_atomic(path, data, suffix=PARTIAL_SUFFIX, fsync=durable)


def pack_float32(values: np.ndarray) -> np.ndarray:
    """float32 (h, w) -> uint8 (h, w, 4): the little-endian bytes of each value."""
    values = np.ascontiguousarray(values, dtype="<f4")
    return values.view(np.uint8).reshape(*values.shape, 4)


def unpack_float32(packed: np.ndarray) -> np.ndarray:
    """uint8 (h, w, 4) -> float32 (h, w); the exact inverse of :func:`pack_float32`."""
    packed = np.ascontiguousarray(packed, dtype=np.uint8)
    return packed.view("<f4").reshape(packed.shape[:-1]).astype(np.float32, copy=False)


def _encode(array: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", array)
    if not ok:
        raise ValueError(f"OpenCV could not encode an array of shape {array.shape} as PNG")
    return buf.tobytes()


def encode_rgb(image: np.ndarray) -> bytes:
    """uint8 (h, w, 3) RGB -> PNG bytes."""
    return _encode(np.ascontiguousarray(image[..., ::-1]))


def encode_distance(distance: np.ndarray) -> bytes:
    """float32 (h, w) metres -> PNG bytes of the packed 4-channel image."""
    return _encode(pack_float32(distance))


def encode_mask(mask: np.ndarray) -> bytes:
    """uint8 (h, w) in {0, 1} -> PNG bytes with 0 / 255."""
    return _encode((np.asarray(mask) > 0).astype(np.uint8) * 255)


def check_png_chunks(data: bytes) -> str | None:
    """What is wrong with the chunk structure of PNG bytes (None when every chunk is whole and
    its CRC matches). Checked before decoding: damaged bytes then give one clear error instead
    of a stray line that libpng prints itself."""
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


def read_png(path: str | os.PathLike, where: str = "") -> np.ndarray:
    """Decode a PNG file exactly as stored (uint8 or uint16, 1/3/4 channels).

    Raises FileNotFoundError when it is missing and ValueError when it is not a complete PNG
    (a truncated file lacks the final IEND chunk). ``where`` (e.g. the CSV row that names the
    file) is appended to every message.
    """
    path = Path(path)
    suffix = f" ({where})" if where else ""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(f"missing file {path}{suffix}") from None
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


def _check(image: np.ndarray, path, where: str, channels: int, hw: tuple[int, int] | None,
           kind: str) -> None:
    suffix = f" ({where})" if where else ""
    found_c = 1 if image.ndim == 2 else image.shape[2]
    if image.dtype != np.uint8:
        raise ValueError(f"{path}: {kind} must be an 8-bit PNG; found {image.dtype}{suffix}")
    if found_c != channels:
        raise ValueError(f"{path}: {kind} must have {channels} channel(s); found {found_c}{suffix}")
    if hw is not None and tuple(image.shape[:2]) != tuple(hw):
        raise ValueError(f"{path}: {kind} must be {hw[1]}x{hw[0]} (WxH); found "
                         f"{image.shape[1]}x{image.shape[0]}{suffix}")


def read_rgb(path, hw: tuple[int, int] | None = None, where: str = "") -> np.ndarray:
    """PNG -> uint8 (h, w, 3) RGB; checks channels and, when given, (h, w)."""
    image = read_png(path, where)
    _check(image, path, where, 3, hw, "RGB image")
    return np.ascontiguousarray(image[..., ::-1])


def read_distance(path, hw: tuple[int, int] | None = None, where: str = "",
                  require_finite: bool = True) -> np.ndarray:
    """Packed PNG -> float32 (h, w) metres; raises ValueError on non-finite values."""
    packed = read_png(path, where)
    _check(packed, path, where, 4, hw, "packed distance")
    distance = unpack_float32(packed)
    if require_finite and not np.all(np.isfinite(distance)):
        bad = int(np.size(distance) - np.count_nonzero(np.isfinite(distance)))
        suffix = f" ({where})" if where else ""
        raise ValueError(f"{path}: {bad} non-finite distance value(s){suffix}")
    return distance


def read_mask(path, hw: tuple[int, int] | None = None, where: str = "") -> np.ndarray:
    """PNG -> uint8 (h, w) in {0, 1}."""
    image = read_png(path, where)
    _check(image, path, where, 1, hw, "mask")
    return (image > 0).astype(np.uint8)
