"""Reading the frames a calibration is refined from (an edge: files in, NumPy out).

A frame is one folder with one image per camera, named by the rig's camera names:
``<name>.png`` (or ``.jpg`` / ``.jpeg``), e.g. ``cam0.png cam1.png cam2.png`` for a rig whose
cameras are called cam0.. (the default names). An optional ``<name>_mask.png`` beside it
(nonzero = valid) is combined with the rig's own mask. A gijax dataset folder (one holding
``manifest.json``, :mod:`gijax.data.reader`) is read as one frame per sample, its images and
masks (the dataset's own rig is not used: the rig given is the one refined).
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from gijax.geometry.rig import Rig

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def _camera_image(folder: Path, name: str) -> Path:
    for suffix in IMAGE_SUFFIXES:
        path = folder / f"{name}{suffix}"
        if path.is_file():
            return path
    raise FileNotFoundError(f"frame {folder}: no image for camera {name!r} (expected "
                            f"{name}.png, {name}.jpg or {name}.jpeg)")


def read_frame_folder(folder, rig: Rig) -> tuple[np.ndarray, np.ndarray]:
    """One frame folder -> images uint8 (N, h, w, 3) and masks float32 (N, h, w)."""
    from gijax.data.images import read_image
    from gijax.io.masks import read_mask

    folder = Path(folder)
    images, masks = [], []
    for name in rig.names:
        path = _camera_image(folder, name)
        img = read_image(path)
        mask_path = folder / f"{name}_mask.png"
        # read_mask checks the size against the image's and names both in its error.
        mask = (read_mask(mask_path, img.shape[:2], label=f"frame {folder}, camera {name!r}")
                if mask_path.is_file() else np.ones(img.shape[:2], np.float32))
        images.append(img)
        masks.append(mask)
    sizes = {im.shape[:2] for im in images}
    if len(sizes) != 1:
        found = ", ".join(f"{n} {i.shape[0]}x{i.shape[1]}" for n, i in zip(rig.names, images))
        raise ValueError(f"frame {folder}: the cameras' images differ in size ({found}); "
                         f"refinement needs one size")
    return np.stack(images), np.stack(masks)


def read_frames(paths: Sequence, rig: Rig, max_frames: Optional[int] = None
                ) -> tuple[np.ndarray, np.ndarray, list]:
    """Frame folders and dataset folders -> images (F, N, h, w, 3) uint8, masks (F, N, h, w)
    float32 and one label per frame (its folder, or ``dataset#sample``), at most
    ``max_frames`` frames (the first ones)."""
    from gijax.data.format import MANIFEST

    images, masks, labels = [], [], []
    for p in paths:
        p = Path(p)
        if not p.is_dir():
            raise FileNotFoundError(f"--frames {p}: not a folder")
        if (p / MANIFEST).is_file():
            from gijax.data.reader import DatasetReader

            reader = DatasetReader(p)
            if reader.names != list(rig.names):
                raise ValueError(f"dataset {p} has cameras {reader.names}; the rig has "
                                 f"{list(rig.names)}")
            for i in range(len(reader)):
                sample = reader[i]
                images.append(np.asarray(sample["images"]))
                masks.append(np.asarray(sample["masks"], np.float32))
                labels.append(f"{p}#{i}")
        else:
            im, m = read_frame_folder(p, rig)
            images.append(im)
            masks.append(m)
            labels.append(str(p))
    if max_frames is not None:
        images, masks, labels = images[:max_frames], masks[:max_frames], labels[:max_frames]
    if not images:
        raise ValueError("no frames given")
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise ValueError(f"frames differ in image size: {sorted(shapes)}")
    return np.stack(images), np.stack(masks), labels

