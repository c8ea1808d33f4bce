"""Reading camera images and masks from ordinary image files (PNG, JPEG, ...) for inference.

Dataset images go through :mod:`gijax.data.reader`; this is for the files a user points a
command at (``gijax predict --images``, ``gijax trt run``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def read_image(path: str | os.PathLike, grey: bool = False) -> np.ndarray:
    """An image as uint8: RGB (h, w, 3), or (h, w) with ``grey`` (masks).

    Grey images are repeated to three channels, an alpha channel is dropped and 16-bit images
    are scaled to 8 bits. FileNotFoundError / ValueError name the file.
    """
    import cv2

    path = str(path)
    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: no such image")
    img = cv2.imread(path, cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: not a readable image")
    if grey:
        return img
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    elif img.shape[-1] == 4:
        img = img[..., :3]
    if img.dtype == np.uint16:
        img = (img / 257.0 + 0.5).astype(np.uint8)
    return np.ascontiguousarray(img[..., ::-1])  # OpenCV reads BGR


def read_mask(path: str | os.PathLike) -> np.ndarray:
    """A validity mask as float32 (h, w): 1 where the file is non-zero, else 0."""
    return (read_image(path, grey=True) > 0).astype(np.float32)
