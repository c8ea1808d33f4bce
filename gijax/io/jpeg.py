"""Telling a complete JPEG file from a truncated one.

libjpeg decodes a file that was cut short (a copy interrupted, a camera's card pulled) as far as
its bytes go, prints "Premature end of JPEG file" on stderr and returns a whole-size image
whose lower part is grey: a half-decoded input that a model would run on without complaint.
The markers say whether the file is whole: the entropy-coded data of the (last) scan starts
after a start-of-scan marker (``FF DA``) and a complete file ends it with the end-of-image
marker (``FF D9``). Thumbnails embedded in an Exif block have scans of their own, but they lie
before the main image's, so the last scan is the main image's; bytes that some cameras append
after the end-of-image marker are allowed.

This module imports only the standard library.
"""

from __future__ import annotations

JPEG_SOI = b"\xff\xd8"          # start of image
JPEG_SOS = b"\xff\xda"          # start of scan
JPEG_EOI = b"\xff\xd9"          # end of image


def is_jpeg(data: bytes) -> bool:
    """Whether ``data`` starts like a JPEG file (start-of-image, then a marker)."""
    return len(data) >= 3 and data[:2] == JPEG_SOI and data[2] == 0xFF


def check_jpeg_complete(data: bytes) -> str | None:
    """What is wrong with JPEG bytes, or None when the last scan is followed by an
    end-of-image marker."""
    if not is_jpeg(data):
        return "not a JPEG file (no start-of-image marker)"
    scan = data.rfind(JPEG_SOS)
    if scan < 0:
        return "no image data (no start-of-scan marker): truncated or damaged"
    if data.find(JPEG_EOI, scan + 2) < 0:
        return (f"truncated: the image data that starts at byte {scan} has no end-of-image "
                f"marker (the file ends at byte {len(data)})")
    return None


__all__ = ["JPEG_EOI", "JPEG_SOI", "JPEG_SOS", "check_jpeg_complete", "is_jpeg"]
