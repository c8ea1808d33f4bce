"""Bounds on the sizes a user can give, checked before anything is allocated or written.

A size that cannot be served should fail in one line naming it, not end in an allocator abort
with a native stack halfway through a command. Two bounds apply:

* :data:`MAX_SIDE` pixels per side for any image or panorama: beyond it, pixel coordinates in
  float32 resolve worse than 1/256 px and OpenCV's own limits come near;
* memory: what one copy of the image needs (its pixels times the bytes each holds while gijax
  works on it) must fit in half the memory this machine has available now
  (:func:`available_memory`; the other half is for the rest of the work).

This module imports only the standard library.
"""

from __future__ import annotations

import os

MAX_SIDE = 32768
# Bytes per pixel gijax holds for one camera image while it works on it: float32 RGB and a
# float32 mask.
CAMERA_BYTES_PER_PIXEL = 16
# Peak memory of `gijax render` per pixel it renders, measured (peak resident set against image
# sizes, paper-train, one sample): about 250 bytes per camera pixel (all cameras of a sample are
# ray-cast together) and 118 per pixel of the label panorama.
RENDER_BYTES_PER_CAMERA_PIXEL = 256
RENDER_BYTES_PER_PANORAMA_PIXEL = 128
# Peak memory of a prediction per output panorama pixel and distance candidate, measured for
# the bundled G16VV-cpu (2.4 KB per pixel at 16 candidates: the cost volume, the U-Net's
# full-resolution stage and the per-candidate probabilities all grow with both).
PREDICT_BYTES_PER_PIXEL_PER_CANDIDATE = 160


def available_memory() -> int:
    """Bytes of memory available to new allocations now (``MemAvailable`` of /proc/meminfo;
    the physical memory where that file does not exist)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 1 << 62


def check_size(what: str, width: int, height: int, bytes_per_pixel: int, copies: int = 1) -> None:
    """Raise ``ValueError`` (one line naming ``what``) when a ``width`` x ``height`` image is
    not positive, has a side beyond :data:`MAX_SIDE`, or would need more than half the available
    memory for ``copies`` copies of ``bytes_per_pixel`` bytes a pixel."""
    if width < 1 or height < 1:
        raise ValueError(f"{what}: {width}x{height} (width x height) must be positive")
    if max(width, height) > MAX_SIDE:
        raise ValueError(f"{what}: {width}x{height} (width x height) has a side beyond the "
                         f"{MAX_SIDE}-pixel bound")
    need = int(width) * int(height) * int(bytes_per_pixel) * int(copies)
    limit = available_memory() // 2
    if need > limit:
        raise ValueError(f"{what}: {width}x{height} (width x height) needs about "
                         f"{need / 2**30:.1f} GiB, more than half of the "
                         f"{2 * limit / 2**30:.1f} GiB this machine has available")


def check_scale(what: str, factor: float) -> float:
    """``factor`` as a float; ``ValueError`` (one line naming ``what``) unless it is finite and
    positive."""
    try:
        value = float(factor)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a positive number; found {factor!r}") from None
    if not (value > 0 and value != float("inf")):
        raise ValueError(f"{what} must be a positive number; found {factor!r}")
    return value


def check_render(cameras: list[tuple[str, int, int]], panorama_wh: tuple[int, int],
                 what: str = "render") -> None:
    """``ValueError`` (one line) unless every camera image (name, width, height) and the label
    panorama (width, height) are positive, within :data:`MAX_SIDE`, and rendering them together
    fits in half the available memory."""
    for name, w, h in cameras:
        check_size(f"{what}: camera {name!r}", w, h, 1)
    pw, ph = panorama_wh
    check_size(f"{what}: the panorama", pw, ph, 1)
    need = (sum(w * h for _, w, h in cameras) * RENDER_BYTES_PER_CAMERA_PIXEL
            + pw * ph * RENDER_BYTES_PER_PANORAMA_PIXEL)
    limit = available_memory() // 2
    if need > limit:
        sizes = ", ".join(f"{w}x{h}" for _, w, h in cameras)
        raise ValueError(f"{what}: cameras {sizes} and a {pw}x{ph} panorama (width x height) "
                         f"need about {need / 2**30:.1f} GiB, more than half of the "
                         f"{2 * limit / 2**30:.1f} GiB this machine has available")


def check_prediction(panorama_hw: tuple[int, int], candidates: int,
                     what: str = "--panorama-size") -> None:
    """``ValueError`` (one line naming ``what``, sizes in its HxW order) unless a prediction
    over a panorama of ``panorama_hw`` (rows, columns) at ``candidates`` distance candidates
    (times the samples of a batch) has sides within :data:`MAX_SIDE` and fits in half the
    available memory."""
    h, w = int(panorama_hw[0]), int(panorama_hw[1])
    given = f"{what} {h}x{w} (rows x columns)"
    if h < 1 or w < 1:
        raise ValueError(f"{given} must be positive")
    if max(h, w) > MAX_SIDE:
        raise ValueError(f"{given} has a side beyond the {MAX_SIDE}-pixel bound")
    need = h * w * PREDICT_BYTES_PER_PIXEL_PER_CANDIDATE * max(int(candidates), 1)
    limit = available_memory() // 2
    if need > limit:
        raise ValueError(f"{given} needs about {need / 2**30:.1f} GiB at {candidates} "
                         f"candidates, more than half of the {2 * limit / 2**30:.1f} GiB this "
                         f"machine has available")


__all__ = ["CAMERA_BYTES_PER_PIXEL", "MAX_SIDE", "PREDICT_BYTES_PER_PIXEL_PER_CANDIDATE",
           "RENDER_BYTES_PER_CAMERA_PIXEL", "RENDER_BYTES_PER_PANORAMA_PIXEL",
           "available_memory", "check_prediction", "check_render", "check_scale",
           "check_size"]
