"""Training data streams with a resumable position: datasets on disk and in-memory arrays.

A stream is an iterator of batches (dicts of numpy arrays: ``surrogates`` (B, N, Hs, Ws, 3),
``masks`` (B, N, Hs, Ws), ``distance`` (B, H, W) metres, ``valid`` (B, H, W)) with a
``state()`` method; a stream factory ``make(state | None) -> stream`` rebuilds the stream at a
saved position. Both kinds here follow :class:`gijax.data.Loader`'s epoch order (a permutation
per ``(seed, epoch)``, dealt round-robin to processes).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Optional

import jax
import numpy as np

from gijax.data.loader import epoch_order, shard_order
from gijax.random_streams import host_rng
from gijax.train.step import BATCH_KEYS, EXTRA_KEYS


class ArrayLoader:
    """Endless, resumable batches from in-memory arrays (each ``(num_samples, ...)``): the
    :data:`~gijax.train.step.BATCH_KEYS` and any of :data:`~gijax.train.step.EXTRA_KEYS`.

    ``batch_size`` is per process; ``state()`` gives the epoch and batch position of the next
    batch, and ``ArrayLoader(..., state=s)`` continues from there.
    """

    def __init__(self, arrays: dict, batch_size: int, seed: int = 0, shuffle: bool = True,
                 process_index: int = 0, process_count: int = 1, state: Optional[dict] = None):
        missing = [k for k in BATCH_KEYS if k not in arrays]
        if missing:
            raise ValueError(f"in-memory training data lacks arrays {missing}; expected {BATCH_KEYS}")
        self.arrays = {k: np.asarray(arrays[k]) for k in BATCH_KEYS + EXTRA_KEYS
                       if k in arrays}
        self.num_samples = len(self.arrays["distance"])
        uneven = [k for k, v in self.arrays.items() if len(v) != self.num_samples]
        if uneven:
            raise ValueError(f"in-memory training data: arrays {uneven} do not hold "
                             f"{self.num_samples} samples like 'distance'")
        if self.num_samples == 0:
            raise ValueError("in-memory training data has no samples")
        self.batch_size, self.seed, self.shuffle = int(batch_size), int(seed), bool(shuffle)
        self.process_index, self.process_count = int(process_index), int(process_count)
        shard = self.num_samples // self.process_count
        self.batches_per_epoch = shard // self.batch_size
        if self.batches_per_epoch == 0:
            raise ValueError(f"batch size {self.batch_size} per process is larger than the "
                             f"{shard} samples each of {self.process_count} process(es) holds")
        self.epoch, self.position = 0, 0
        if state is not None:
            for k in ("seed", "batch_size", "num_samples"):
                if k in state and state[k] != getattr(self, k):
                    raise ValueError(f"data position was saved with {k}={state[k]!r}; this data "
                                     f"stream has {k}={getattr(self, k)!r}")
            self.epoch, self.position = int(state["epoch"]), int(state["position"])
            if self.position >= self.batches_per_epoch:
                self.epoch, self.position = self.epoch + 1, 0

    def state(self) -> dict:
        return {"epoch": self.epoch, "position": self.position, "seed": self.seed,
                "batch_size": self.batch_size, "num_samples": self.num_samples}

    def __iter__(self):
        return self

    def __next__(self) -> dict:
        order = shard_order(epoch_order(self.num_samples, self.seed, self.epoch, self.shuffle),
                            self.process_index, self.process_count)
        idx = order[self.position * self.batch_size:(self.position + 1) * self.batch_size]
        self.position += 1
        if self.position == self.batches_per_epoch:
            self.epoch, self.position = self.epoch + 1, 0
        return {k: v[idx] for k, v in self.arrays.items()}

    def close(self) -> None:
        pass


def array_stream_factory(arrays: dict, batch_size: int, seed: int = 0) -> Callable:
    """Factory for :class:`ArrayLoader` streams with this process's share of a global batch."""
    per_process = batch_size // jax.process_count()

    def make(state=None):
        return ArrayLoader(arrays, per_process, seed, True, jax.process_index(),
                           jax.process_count(), state)

    return make


def open_dataset(path: str | Path, what: str = "training", allow_partial: bool = False):
    """A dataset reader with clear errors for a missing or empty folder (and, for gijax's
    layout, for an incomplete one unless ``allow_partial``).

    The layout is detected from the folder's files
    (:func:`gijax.data.release.detect_layout`): gijax's own
    (:class:`gijax.data.DatasetReader`) or the paper's released layout
    (:class:`gijax.data.release.ReleaseDatasetReader`). For the release layout the
    data_partitions.json partition is ``train`` for training and ``validate`` otherwise, as in
    the release; ``DIR@KEY`` selects partition ``KEY`` instead.
    """
    from gijax.data.release import detect_layout, open_reader

    text = str(path)
    split = "train" if what == "training" else "validate"
    path = Path(text)
    if not path.exists() and "@" in text:
        head, _, key = text.rpartition("@")
        if Path(head).is_dir() and key:
            path, split = Path(head), key
    if not path.exists():
        raise FileNotFoundError(f"{what} data folder {path} does not exist")
    kw = {"allow_partial": allow_partial} if detect_layout(path) == "gijax" else {}
    reader = open_reader(path, split=split, **kw)
    if len(reader) == 0:
        raise ValueError(f"{what} data folder {path} has no samples")
    return reader


def dataset_stream_factory(reader, rig, batch_size: int, seed: int, surrogate_hw, *,
                           mask_augmentation: bool = False, workers: int = 2,
                           what: str = "training", augment=None, pool=None) -> Callable:
    """Factory for :class:`gijax.data.Loader` streams over ``reader`` (global ``batch_size``);
    ``augment`` is the loader's :class:`gijax.data.augment.AugmentConfig` (None: off); ``pool``
    a shared executor to load in (see :class:`gijax.data.Loader`)."""
    from gijax.data import Loader
    from gijax.geometry.panorama import Panorama

    per_process = batch_size // jax.process_count()
    share = len(reader) // jax.process_count()
    if per_process > share:
        raise ValueError(f"batch size {batch_size} is larger than the {what} data "
                         f"({len(reader)} samples in {getattr(reader, 'root', 'the dataset')}"
                         f"{' over %d processes' % jax.process_count() if jax.process_count() > 1 else ''})")

    def make(state=None):
        if state is not None:
            state = {k: v for k, v in state.items() if k not in ("process_index",)}
        return Loader(reader, rig, batch_size=per_process, seed=seed,
                      surrogate=Panorama.hemisphere(*surrogate_hw), shuffle=True,
                      mask_augmentation=mask_augmentation, workers=workers, augment=augment,
                      process_index=jax.process_index(), process_count=jax.process_count(),
                      state=state, pool=pool)

    return make


RIG_KEY = "rig_index"


class MixedStream:
    """Batches from several training streams, one stream per batch: the stream of step ``k`` is
    drawn from ``(seed, k)`` with probabilities proportional to ``weights`` (each dataset's
    size), so a batch holds one rig's samples and the choice does not depend on timing.

    Each batch carries ``rig_index`` (which stream); ``state()`` holds the step count and every
    stream's own position, and ``make`` from that state continues exactly.
    """

    def __init__(self, factories, weights, seed: int, state: Optional[dict] = None):
        w = np.asarray(weights, np.float64)
        if len(factories) != len(w) or len(w) == 0 or np.any(w <= 0):
            raise ValueError(f"a mixed stream needs one positive weight per stream; found "
                             f"{len(factories)} streams and weights {w.tolist()}")
        self.p = w / w.sum()
        self.seed = int(seed)
        streams_state = [None] * len(factories)
        self.step = 0
        if state is not None:
            if len(state.get("streams", [])) != len(factories):
                raise ValueError(f"data position was saved for {len(state.get('streams', []))} "
                                 f"training datasets; this run has {len(factories)}")
            self.step, streams_state = int(state["step"]), list(state["streams"])
        self.streams = [f(s) for f, s in zip(factories, streams_state)]

    def choice(self, step: int) -> int:
        return int(host_rng(self.seed, "mixture", step).choice(len(self.p), p=self.p))

    def state(self) -> dict:
        return {"step": self.step, "streams": [s.state() for s in self.streams]}

    def __iter__(self):
        return self

    def __next__(self) -> dict:
        i = self.choice(self.step)
        batch = dict(next(self.streams[i]))
        self.step += 1
        batch[RIG_KEY] = i
        return batch

    def close(self) -> None:
        for s in self.streams:
            close = getattr(s, "close", None)
            if close is not None:
                close()


def mixed_stream_factory(factories, weights, seed: int) -> Callable:
    """Factory for :class:`MixedStream` over stream factories (one per training dataset)."""
    def make(state=None):
        return MixedStream(factories, weights, seed, state)

    return make


def validation_batches(reader, rig, batch_size: int, surrogate_hw, limit: int = 0):
    """The validation set in dataset order, once, in batches (the last one may be smaller)."""
    from gijax.data import Loader
    from gijax.geometry.panorama import Panorama

    n = min(batch_size, len(reader))
    loader = Loader(reader, rig, batch_size=n, seed=0, surrogate=Panorama.hemisphere(*surrogate_hw),
                    shuffle=False, workers=1, drop_last=False, num_epochs=1)
    try:
        for i, batch in enumerate(loader):
            if limit and i >= limit:
                break
            yield batch
    finally:
        loader.close()
