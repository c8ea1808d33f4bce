"""PNG encoding of the dataset's arrays.

* RGB images: uint8 (h, w, 3) RGB in memory, an 8-bit 3-channel PNG on disk (OpenCV stores the
  channels as BGR; conversion happens here, so callers only ever see RGB).
* Distances: float32 (h, w) metres, packed bit-exactly into an 8-bit 4-channel PNG: the four
  little-endian bytes of each float32 are the four channels of its pixel (byte 0 = the first
  channel as OpenCV reads it). PNG is lossless, so the round trip is bit-exact, NaN payloads
  and infinities included.
* Masks: uint8 (h, w) in {0, 1} in memory, an 8-bit 1-channel PNG with 0 / 255 on disk (so the
  files are viewable); they are read by :func:`gijax.io.masks.read_mask` (nonzero = valid, any
  bit depth).

The dataset writer writes these bytes with :func:`gijax.io.paths.write_bytes_atomic`, its
temporaries named ``*`` + :data:`PARTIAL_SUFFIX` so the leftovers of a killed writer can be found.
"""

from __future__ import annotations

import cv2
import numpy as np

from gijax.io.png import read_png

PARTIAL_SUFFIX = ".partial"


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
