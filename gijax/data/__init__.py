"""Datasets on disk (gijax's own layout and the paper's released one) and the batch loader."""

from gijax.data.augment import augment_masks, erase_rectangle
from gijax.data.loader import Loader, epoch_order, shard_order
from gijax.data.pngio import pack_float32, unpack_float32
from gijax.data.reader import DatasetReader, Skipped
from gijax.data.release import ReleaseDatasetReader, detect_layout, open_reader
from gijax.data.writer import DatasetWriter, sample_seed, write_dataset

__all__ = [
    "augment_masks", "erase_rectangle", "Loader", "epoch_order",
    "shard_order", "pack_float32", "unpack_float32", "DatasetReader", "Skipped",
    "ReleaseDatasetReader", "detect_layout", "open_reader",
    "DatasetWriter", "sample_seed", "write_dataset",
]
