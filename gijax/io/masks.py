"""Masks from files: the one mask reader (rig files, ``--masks``, datasets), attaching masks to a
rig, and the warning for a rig used for stereo without them.

A rig mask marks the pixels of one camera that see the world (nonzero) rather than the rig's own
body (zero). Without one, the body in every image is matched as if it were scene, which pulls
the distances near it towards the body's. Calibration files (Kalibr, basalt) hold no masks, so
an imported rig has none until they are attached (``gijax rig import CALIB --masks ...``).
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from gijax.geometry.layouts import BUILTIN_LAYOUTS
from gijax.geometry.rig import Rig
from gijax.io.jpeg import check_jpeg_complete, is_jpeg
from gijax.io.png import is_png, read_png

IMPORT_HINT = "gijax rig import CALIB --masks m0.png m1.png ... --out rig.yaml"


class UnmaskedRigWarning(UserWarning):
    """A rig whose cameras have no masks is used for stereo (filterable by this category)."""


def read_mask(path, hw: tuple[int, int] | None = None, label: str = "") -> np.ndarray:
    """A mask image as float32 (H, W): 1 where any colour channel is nonzero (alpha ignored),
    else 0, whatever the bit depth (1-, 8- or 16-bit, grey or colour).

    Every mask of gijax is read here: rig files, ``--masks`` of the commands, and datasets.

    Args:
      path: the image (PNG, checked for truncation and damage first; JPEG, checked for
        truncation; other formats OpenCV reads).
      hw: (height, width) the mask must have (its camera's image size), or None.
      label: starts every error and names where the mask was asked for (the rig file and
        camera, the command-line option and camera, or the dataset row).

    Raises FileNotFoundError for a missing file and ValueError for an unreadable one or one of
    another size (expected and found sizes, W x H).
    """
    import cv2

    path = Path(path)
    prefix = f"{label}: " if label else ""
    if not path.is_file():
        raise FileNotFoundError(f"{prefix}missing file {path} (a mask image)")
    if is_png(path):
        img = read_png(path, label)
    else:
        data = path.read_bytes()
        problem = check_jpeg_complete(data) if is_jpeg(data) else None
        if problem:
            raise ValueError(f"{prefix}{path}: {problem}")
        # UNCHANGED: a 16-bit mask read as 8-bit grey would turn values below 256 into 0.
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ValueError(f"{prefix}{path} is not a readable image (expected a mask image, "
                             f"e.g. a PNG)")
    if img.ndim == 3:
        colour = img[..., :3] if img.shape[2] >= 3 else img[..., :1]
        img = colour.max(axis=2)
    if hw is not None and tuple(img.shape) != tuple(hw):
        raise ValueError(f"{prefix}mask {path} is {img.shape[1]}x{img.shape[0]} px but the "
                         f"camera's image is {hw[1]}x{hw[0]} px (width x height); a mask must "
                         f"be the size of its camera's image")
    return (img > 0).astype(np.float32)


def attach_masks(rig: Rig, paths: Sequence, source: str, option: str = "--masks") -> Rig:
    """``rig`` with camera i's mask read from ``paths[i]`` (one per camera, in camera order).

    ``source`` (the rig's file or name) and ``option`` only name things in errors: a count
    mismatch lists the cameras; a size mismatch names the file, the camera and both sizes.
    """
    if len(paths) != rig.num_cameras:
        raise ValueError(f"{option}: {len(paths)} mask file(s) given for the "
                         f"{rig.num_cameras} cameras of {source} "
                         f"({', '.join(rig.names)}); give one PNG per camera, in camera order")
    masks = tuple(read_mask(p, (cam.height, cam.width), f"{option}: camera {name!r}")
                  for p, cam, name in zip(paths, rig.cameras, rig.names))
    return rig.replace(masks=masks)


def rename_cameras(rig: Rig, names: Sequence[str], source: str,
                   option: str = "--names") -> Rig:
    """``rig`` with its cameras renamed (one distinct name per camera, in camera order)."""
    names = tuple(str(n) for n in names)
    if len(names) != rig.num_cameras:
        raise ValueError(f"{option}: {len(names)} name(s) given for the {rig.num_cameras} "
                         f"cameras of {source} ({', '.join(rig.names)})")
    if len(set(names)) != len(names):
        raise ValueError(f"{option}: camera names must be distinct; found {list(names)}")
    # Names become part of the mask files' names beside a saved rig.
    bad = [n for n in names if not re.fullmatch(r"[\w.-]+", n)]
    if bad:
        raise ValueError(f"{option}: camera names may hold only letters, digits, '_', '.' and "
                         f"'-'; found {bad}")
    return rig.replace(names=names)


def unmasked_cameras(rig: Rig) -> tuple[str, ...]:
    """Names of the cameras that have no mask."""
    return tuple(n for n, m in zip(rig.names, rig.masks) if m is None)


def unmasked_message(rig: Rig, source) -> Optional[str]:
    """The note that ``rig`` (loaded from ``source``) has cameras without masks, or None when
    all have one or ``source`` is a built-in layout (see :func:`warn_if_unmasked`)."""
    if isinstance(source, str) and source in BUILTIN_LAYOUTS:
        return None
    missing = unmasked_cameras(rig)
    if not missing:
        return None
    which = (f"camera {missing[0]} has" if len(missing) == 1 else
             f"cameras {', '.join(missing)} have")
    return (f"{source}: {which} no mask; the rig body will be matched as scene; add masks "
            f"with `{IMPORT_HINT}`")


def warn_if_unmasked(rig: Rig, source, other_masks: bool = False) -> tuple[str, ...]:
    """Warn (:class:`UnmaskedRigWarning`) when a rig loaded from a file is used for stereo with
    cameras that have no mask; returns the names warned about.

    Only rigs from files are checked: a built-in layout is rendered, and its body (the occluder)
    is masked by construction. A rig file or calibration without masks may describe a rendered
    rig with no body just as well as a real one whose masks were never attached, and cannot
    tell which; the warning is the cheap side of that doubt, and the message says how to add
    masks. Rigs read from a dataset are not checked here: the dataset's samples carry their own
    masks, which replace the rig's in training and evaluation.

    Args:
      rig: the rig about to be used.
      source: what it was loaded from (a built-in name or a path), for the message.
      other_masks: masks are supplied with the images (e.g. ``gijax predict --masks``) and
        replace the rig's, so there is nothing to warn about.
    """
    message = None if other_masks else unmasked_message(rig, source)
    if message is None:
        return ()
    warnings.warn(message, UnmaskedRigWarning, stacklevel=2)
    return unmasked_cameras(rig)


def import_rig(calibration, masks: Optional[Sequence] = None,
               names: Optional[Sequence[str]] = None, frame_camera: int = 0) -> Rig:
    """A rig from a calibration (anything :func:`gijax.io.rigfile.load_rig` reads), renamed and
    with masks attached when given (one per camera, in camera order; names apply first, so
    errors use them)."""
    from gijax.io.rigfile import load_rig

    rig = load_rig(calibration, frame_camera=frame_camera)
    if names:
        rig = rename_cameras(rig, names, str(calibration))
    if masks:
        rig = attach_masks(rig, masks, str(calibration))
    return rig


__all__ = ["IMPORT_HINT", "UnmaskedRigWarning", "attach_masks", "import_rig", "read_mask",
           "rename_cameras", "unmasked_cameras", "unmasked_message", "warn_if_unmasked"]
