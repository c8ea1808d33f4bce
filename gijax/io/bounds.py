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


__all__ = ["CAMERA_BYTES_PER_PIXEL", "MAX_SIDE", "available_memory", "check_size"]
