"""TensorBoard event files (``events.out.tfevents.*``): written by tensorboardX, which builds
the ``Event`` / ``Summary`` protocol buffers and the TFRecord framing with its CRC-32C, and read
back here for the one rewrite a resumed training run needs (:func:`drop_events_after`).

The writer is tensorboardX's synchronous ``EventsWriter`` rather than its ``SummaryWriter``:
the latter hands events to a background thread, so its ``flush`` does not mean the events are
in the file, and a run killed right after logging a step could lose it. Here an event is in
the file (and flushed to disk) when :meth:`EventWriter.flush` returns.
"""

from __future__ import annotations

import os
import secrets
import struct
import time
from pathlib import Path

import numpy as np

from gijax.io.paths import atomic_path

# TFRecord frame: uint64 length, masked CRC of the length, payload, masked CRC of the payload.
_LENGTH, _CRC = 8, 4


class EventWriter:
    """Appends scalars and images to a new ``LOGDIR/events.out.tfevents.<time>.<host>.<pid>.<id>``
    (a new file per writer, so a run resumed in the same second never overwrites the last one's
    events). The file starts with TensorBoard's version event (step 0)."""

    def __init__(self, logdir: str | os.PathLike):
        from tensorboardX.event_file_writer import EventsWriter

        self.logdir = Path(logdir)
        self.logdir.mkdir(parents=True, exist_ok=True)
        suffix = f".{os.getpid()}.{secrets.token_hex(4)}"
        self._writer = EventsWriter(str(self.logdir / "events"), suffix)
        self.path = next(self.logdir.glob(f"events.out.tfevents.*{suffix}"))

    def _write(self, step: int, summary) -> None:
        from tensorboardX.proto.event_pb2 import Event

        self._writer.write_event(Event(wall_time=time.time(), step=int(step), summary=summary))

    def scalars(self, step: int, values: dict) -> None:
        """One event at ``step`` holding a float scalar per ``tag: value``."""
        from tensorboardX.proto.summary_pb2 import Summary
        from tensorboardX.summary import scalar

        self._write(step, Summary(value=[v for tag, x in values.items()
                                         for v in scalar(tag, float(x)).value]))

    def image(self, step: int, tag: str, rgb: np.ndarray) -> None:
        """An image at ``step``; ``rgb``: (H, W, 3) uint8."""
        from tensorboardX.summary import image

        self._write(step, image(tag, np.asarray(rgb, np.uint8), dataformats="HWC"))

    def flush(self) -> None:
        self._writer.flush()

    def close(self) -> None:
        self._writer.close()


def read_event_records(data: bytes) -> list[bytes]:
    """The serialised events of the complete, intact frames at the start of an event file's
    bytes (reading stops at a frame cut short or damaged, e.g. by a kill mid-write)."""
    from tensorboardX.record_writer import masked_crc32c

    out, pos, head = [], 0, _LENGTH + _CRC
    while pos + head <= len(data):
        header = data[pos:pos + _LENGTH]
        (length,) = struct.unpack("<Q", header)
        end = pos + head + length + _CRC
        if end > len(data) or struct.unpack("<I", data[pos + _LENGTH:pos + head])[0] != \
                masked_crc32c(header):
            break
        payload = data[pos + head:end - _CRC]
        if struct.unpack("<I", data[end - _CRC:end])[0] != masked_crc32c(payload):
            break
        out.append(payload)
        pos = end
    return out


def read_events(path: str | os.PathLike) -> list:
    """The intact events of an event file, as tensorboardX's ``Event`` messages."""
    from tensorboardX.proto.event_pb2 import Event

    return [Event.FromString(r) for r in read_event_records(Path(path).read_bytes())]


def drop_events_after(path: str | os.PathLike, step: int) -> None:
    """Rewrite an event file without its events of steps after ``step``, and without a frame
    cut short by a kill (atomically; untouched when there is nothing to drop)."""
    from tensorboardX.proto.event_pb2 import Event
    from tensorboardX.record_writer import RecordWriter

    path = Path(path)
    data = path.read_bytes()
    records = read_event_records(data)
    kept = [r for r in records if Event.FromString(r).step <= step]
    if len(kept) == len(records) and sum(len(r) + 16 for r in records) == len(data):
        return
    with atomic_path(path) as tmp:
        writer = RecordWriter(str(tmp))
        for record in kept:
            writer.write(record)
        writer.close()


__all__ = ["EventWriter", "drop_events_after", "read_event_records", "read_events"]
