"""TensorBoard event files: what gijax.io.events writes, read back by an independent reader
(TFRecord framing checked here with tensorboardX's CRC, events parsed by tensorboardX's own
``Event`` protocol buffer), and the rewrite a resumed run needs."""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np

from gijax.io.events import EventWriter, drop_events_after


def event_file_records(path: Path) -> list:
    """Every TFRecord frame of an event file as a parsed ``Event``; both masked CRC-32C values
    of every frame are checked, and the file must end at a frame boundary."""
    from tensorboardX.proto.event_pb2 import Event
    from tensorboardX.record_writer import masked_crc32c

    data, out, pos = Path(path).read_bytes(), [], 0
    while pos < len(data):
        (n,) = struct.unpack_from("<Q", data, pos)
        assert struct.unpack_from("<I", data, pos + 8)[0] == masked_crc32c(data[pos:pos + 8])
        payload = data[pos + 12:pos + 12 + n]
        assert struct.unpack_from("<I", data, pos + 12 + n)[0] == masked_crc32c(payload)
        out.append(Event.FromString(payload))
        pos += 16 + n
    assert pos == len(data)
    return out


def test_masked_crc_is_tfrecords():
    """The CRC the framing is checked with: CRC-32C's standard check value, masked as TFRecord
    does (rotate right by 15, add 0xA282EAD8)."""
    from tensorboardX.crc32c import crc32c
    from tensorboardX.record_writer import masked_crc32c

    assert crc32c(b"123456789") == 0xE3069283
    c = 0xE3069283
    assert masked_crc32c(b"123456789") == (((c >> 15) | (c << 17)) + 0xA282EAD8) & 0xFFFFFFFF


def test_scalars_and_images_read_back_with_their_tags_and_steps(tmp_path):
    rgb = np.zeros((5, 7, 3), np.uint8)
    rgb[..., 0], rgb[1, 2] = 200, (10, 20, 30)
    writer = EventWriter(tmp_path / "tb")
    writer.scalars(1, {"train/loss": 0.5, "train/lr": 1e-3})
    writer.scalars(2, {"val/mae": 0.25})
    writer.image(2, "val/prediction_above_label_below/0", rgb)
    writer.flush()                                  # in the file now, before close
    events = event_file_records(writer.path)
    writer.close()
    assert writer.path.parent == tmp_path / "tb"
    assert writer.path.name.startswith("events.out.tfevents.")
    assert events[0].file_version == "brain.Event:2" and events[0].step == 0
    got = [(e.step, v.tag, v.simple_value) for e in events[1:3] for v in e.summary.value]
    assert got == [(1, "train/loss", 0.5), (1, "train/lr", np.float32(1e-3)),
                   (2, "val/mae", 0.25)]
    (value,) = events[3].summary.value
    assert (events[3].step, value.tag) == (2, "val/prediction_above_label_below/0")
    assert (value.image.height, value.image.width, value.image.colorspace) == (5, 7, 3)
    png = cv2.imdecode(np.frombuffer(value.image.encoded_image_string, np.uint8),
                       cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(png[..., ::-1], rgb)


def test_two_writers_in_one_second_keep_both_files(tmp_path):
    first, second = EventWriter(tmp_path), EventWriter(tmp_path)
    first.scalars(1, {"a": 1.0})
    second.scalars(2, {"a": 2.0})
    first.close()
    second.close()
    assert first.path != second.path
    assert [e.step for e in event_file_records(first.path)] == [0, 1]
    assert [e.step for e in event_file_records(second.path)] == [0, 2]


def test_drop_events_after_keeps_earlier_steps_and_drops_a_cut_frame(tmp_path):
    writer = EventWriter(tmp_path)
    for step in range(1, 5):
        writer.scalars(step, {"train/loss": float(step)})
    writer.close()
    whole = writer.path.read_bytes()
    drop_events_after(writer.path, 9)                # nothing to drop: the file is untouched
    assert writer.path.read_bytes() == whole
    with open(writer.path, "ab") as f:
        f.write(b"\x30\x00\x00")                     # a frame cut short by a kill
    drop_events_after(writer.path, 2)
    events = event_file_records(writer.path)
    assert [e.step for e in events] == [0, 1, 2]
    assert [v.simple_value for e in events[1:] for v in e.summary.value] == [1.0, 2.0]
    assert sorted(p.name for p in tmp_path.iterdir()) == [writer.path.name]
