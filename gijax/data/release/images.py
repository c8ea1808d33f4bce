"""Image files as the release's ``mvs_utils.image_io`` reads them: BGR colour, float32
distances packed in 4-channel PNGs, masks valid where greyscale is 255."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from gijax.data import pngio
from gijax.data.release.layout import MANIFEST
from gijax.io.png import is_png, read_png


def _read_any(path: Path, where: str, flags=cv2.IMREAD_UNCHANGED) -> np.ndarray:
    suffix = f" ({where})" if where else ""
    if not path.is_file():
        raise FileNotFoundError(f"missing file {path}{suffix}")
    if is_png(path):
        image = read_png(path, where)  # detects truncated PNGs
        if flags == cv2.IMREAD_GRAYSCALE and image.ndim == 3:
            code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
            image = cv2.cvtColor(image, code)
        return image
    image = cv2.imread(str(path), flags)
    if image is None:
        raise ValueError(f"{path}: OpenCV cannot decode this image{suffix}")
    return image


def _check_hw(image, hw, path, what, where):
    if tuple(image.shape[:2]) != tuple(hw):
        raise ValueError(f"{path}: {what} must be {hw[1]}x{hw[0]} (WxH, from {MANIFEST}); found "
                         f"{image.shape[1]}x{image.shape[0]}" + (f" ({where})" if where else ""))


def read_release_rgb(path: Path, hw, where: str = "") -> np.ndarray:
    """A colour image as the release reads it (BGR), returned uint8 (h, w, 3) RGB."""
    image = _read_any(path, where)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"{path}: colour image must be 8-bit with 3 channels; found "
                         f"{image.dtype} with shape {image.shape}"
                         + (f" ({where})" if where else ""))
    _check_hw(image, hw, path, "colour image", where)
    return np.ascontiguousarray(image[..., ::-1])


def read_release_distance(path: Path, hw, where: str = "") -> np.ndarray:
    """A float32-in-4-channel-PNG distance image, metres (h, w)."""
    image = _read_any(path, where)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 4:
        raise ValueError(f"{path}: distance image must be an 8-bit 4-channel PNG (float32 bytes); "
                         f"found {image.dtype} with shape {image.shape}"
                         + (f" ({where})" if where else ""))
    _check_hw(image, hw, path, "distance image", where)
    return pngio.unpack_float32(image)


def read_release_mask(path: Path, hw, where: str = "") -> np.ndarray:
    """A mask as the release reads it (greyscale == 255 is valid), uint8 (h, w) in {0, 1}."""
    image = _read_any(path, where, cv2.IMREAD_GRAYSCALE)
    if image.dtype != np.uint8:
        raise ValueError(f"{path}: mask must be 8-bit; found {image.dtype}")
    _check_hw(image, hw, path, "mask", where)
    return (image == 255).astype(np.uint8)
