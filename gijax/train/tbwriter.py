"""A minimal TensorBoard event-file writer (no tensorflow / tensorboard / protobuf needed).

TensorBoard reads ``events.out.tfevents.*`` files: TFRecord framing (little-endian uint64
length, masked CRC-32C of the length, the payload, masked CRC-32C of the payload) around
serialised ``Event`` protocol buffers. The few message fields used here are encoded by hand:

* Event: wall_time (1, double), step (2, int64), file_version (3, string), summary (5).
* Summary: value (1, repeated). Summary.Value: tag (1, string), simple_value (2, float),
  image (4). Summary.Image: height (1), width (2), colorspace (3), encoded_image_string (4, PNG).
"""

from __future__ import annotations

import os
import socket
import struct
import time
from pathlib import Path

import numpy as np


def _crc32c_table() -> list[int]:
    poly = 0x82F63B78                       # Castagnoli polynomial, reflected
    table = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ poly if c & 1 else c >> 1
        table.append(c)
    return table


_TABLE = _crc32c_table()


def crc32c(data: bytes) -> int:
    """CRC-32C (Castagnoli) of ``data``; crc32c(b'123456789') == 0xE3069283."""
    crc = 0xFFFFFFFF
    table = _TABLE
    for b in data:
        crc = table[(crc ^ b) & 0xFF] ^ (crc >> 8)
    return crc ^ 0xFFFFFFFF


def masked_crc(data: bytes) -> int:
    """TFRecord's masked CRC: rotate right by 15 and add 0xA282EAD8 (mod 2^32)."""
    c = crc32c(data)
    return (((c >> 15) | (c << 17)) + 0xA282EAD8) & 0xFFFFFFFF


def tfrecord(payload: bytes) -> bytes:
    """One TFRecord frame around ``payload``."""
    header = struct.pack("<Q", len(payload))
    return (header + struct.pack("<I", masked_crc(header)) + payload
            + struct.pack("<I", masked_crc(payload)))


def _varint(n: int) -> bytes:
    n &= (1 << 64) - 1                      # int64 negatives are ten-byte varints
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _key(field: int, wire: int) -> bytes:
    return _varint((field << 3) | wire)


def _bytes_field(field: int, data: bytes) -> bytes:
    return _key(field, 2) + _varint(len(data)) + data


def encode_event(step: int, wall_time: float, *, file_version: str | None = None,
                 values: bytes | None = None) -> bytes:
    """Serialised Event; ``values`` is the concatenation of encoded Summary.Value fields."""
    out = _key(1, 1) + struct.pack("<d", wall_time) + _key(2, 0) + _varint(int(step))
    if file_version is not None:
        out += _bytes_field(3, file_version.encode())
    if values is not None:
        out += _bytes_field(5, values)
    return out


def scalar_value(tag: str, value: float) -> bytes:
    """Encoded Summary.value entry holding a float scalar."""
    body = _bytes_field(1, tag.encode()) + _key(2, 5) + struct.pack("<f", float(value))
    return _bytes_field(1, body)


def image_value(tag: str, png: bytes, height: int, width: int, channels: int = 3) -> bytes:
    """Encoded Summary.value entry holding a PNG image."""
    img = (_key(1, 0) + _varint(height) + _key(2, 0) + _varint(width) + _key(3, 0)
           + _varint(channels) + _bytes_field(4, png))
    return _bytes_field(1, _bytes_field(1, tag.encode()) + _bytes_field(4, img))


def _read_varint(data: bytes, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if pos >= len(data):
            raise ValueError("truncated varint")
        b = data[pos]
        value |= (b & 0x7F) << shift
        pos += 1
        if not b & 0x80:
            return value, pos
        shift += 7


def event_step(event: bytes) -> int:
    """The ``step`` field (2) of a serialised Event (0 when absent, as protobuf defines)."""
    pos = 0
    while pos < len(event):
        key, pos = _read_varint(event, pos)
        field, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = _read_varint(event, pos)
            if field == 2:
                return value - (1 << 64) if value >= 1 << 63 else value
        elif wire == 1:
            pos += 8
        elif wire == 5:
            pos += 4
        elif wire == 2:
            length, pos = _read_varint(event, pos)
            pos += length
        else:
            raise ValueError(f"unsupported protobuf wire type {wire}")
    return 0


def read_records(data: bytes) -> list[bytes]:
    """The payloads of the complete, intact TFRecord frames at the start of ``data`` (reading
    stops at a frame cut short or damaged, e.g. by a kill in the middle of a write)."""
    out, pos = [], 0
    while pos + 12 <= len(data):
        header = data[pos:pos + 8]
        (length,) = struct.unpack("<Q", header)
        end = pos + 12 + length + 4
        if end > len(data) or struct.unpack("<I", data[pos + 8:pos + 12])[0] != masked_crc(header):
            break
        payload = data[pos + 12:pos + 12 + length]
        if struct.unpack("<I", data[end - 4:end])[0] != masked_crc(payload):
            break
        out.append(payload)
        pos = end
    return out


def drop_events_after(path: str | os.PathLike, step: int) -> None:
    """Rewrite an event file without its events of steps after ``step`` (atomically)."""
    path = Path(path)
    data = path.read_bytes()
    records = read_records(data)
    kept = [r for r in records if event_step(r) <= step]
    if len(kept) == len(records) and sum(len(r) + 16 for r in records) == len(data):
        return
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_bytes(b"".join(tfrecord(r) for r in kept))
    os.replace(tmp, path)


class EventWriter:
    """Appends scalars and images to ``LOGDIR/events.out.tfevents.<time>.<host>``."""

    def __init__(self, logdir: str | os.PathLike):
        self.logdir = Path(logdir)
        self.logdir.mkdir(parents=True, exist_ok=True)
        name = f"events.out.tfevents.{int(time.time())}.{socket.gethostname()}.{os.getpid()}"
        self.path = self.logdir / name
        self._f = open(self.path, "ab")
        self._write(encode_event(0, time.time(), file_version="brain.Event:2"))

    def _write(self, event: bytes) -> None:
        self._f.write(tfrecord(event))

    def scalars(self, step: int, values: dict) -> None:
        payload = b"".join(scalar_value(k, v) for k, v in values.items())
        self._write(encode_event(step, time.time(), values=payload))

    def image(self, step: int, tag: str, rgb: np.ndarray) -> None:
        """``rgb``: (H, W, 3) uint8."""
        import cv2

        ok, png = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
        if not ok:
            raise ValueError(f"could not PNG-encode image {tag!r} of shape {rgb.shape}")
        h, w = rgb.shape[:2]
        self._write(encode_event(step, time.time(), values=image_value(tag, png.tobytes(), h, w)))

    def flush(self) -> None:
        self._f.flush()

    def close(self) -> None:
        self._f.close()
