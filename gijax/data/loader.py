"""Batches for training: reader -> per-camera surrogate images -> stacked numpy batches.

Order: every epoch is a permutation of the samples drawn from ``(seed, epoch)`` (identical on
every process), trimmed to a multiple of ``process_count`` and dealt round-robin, so process k
gets ``order[k::process_count]``: the shards are disjoint, equally long and together cover the
trimmed epoch. Each process cuts its shard into batches. Samples are loaded by a thread pool
(PNG decoding and the jitted surrogate resampling release the GIL) a bounded number of batches
ahead; batches come out in schedule order regardless of which thread finishes first, so the
stream depends only on ``(seed, epoch)``, never on timing.

``loader.state()`` is ``{epoch, position}`` of the next batch to be yielded (plus the settings
it depends on); ``Loader(..., state=s)`` continues with exactly the batches that would have
followed.
"""

from __future__ import annotations

import collections
import concurrent.futures
import math
from typing import Iterator

import jax
import jax.numpy as jnp
import numpy as np

from gijax.data.augment import AugmentConfig, augment_masks, augment_sample
from gijax.evaluate.labels import usable_label
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import Rig, is_homogeneous
from gijax.random_streams import device_key, host_rng
from gijax.sweep.surrogate import (resample_surrogates, surrogate_image, surrogate_images,
                                   surrogate_maps)

_surrogate_one = jax.jit(surrogate_image, static_argnames=("pano",))
_augment = jax.jit(augment_sample, static_argnames=("config",))
# Settings a saved state is only valid for.
_STATE_KEYS = ("seed", "batch_size", "shuffle", "process_index", "process_count", "num_samples",
               "drop_last")


def epoch_order(num_samples: int, seed: int, epoch: int, shuffle: bool = True) -> np.ndarray:
    """The global sample order of one epoch (the same on every process)."""
    if not shuffle:
        return np.arange(num_samples)
    return host_rng(seed, "shuffle", epoch).permutation(num_samples)


def shard_order(order: np.ndarray, process_index: int, process_count: int) -> np.ndarray:
    """This process's share of an epoch order: equal-length, disjoint round-robin shards."""
    per = len(order) // process_count
    return order[: per * process_count][process_index::process_count]


# One compiled resampling per image size; the grids depend only on the rig, so the loader
# computes them once instead of per sample (about 3x faster at the paper's size).
_resample = jax.jit(resample_surrogates)


class Loader:
    """Iterator of training batches (dicts of numpy arrays).

    Each batch: ``surrogates`` float32 (B, Ncam, Hs, Ws, 3) surrogate RGB in [0, 1], 0 where
    invalid; ``masks`` float32 (B, Ncam, Hs, Ws) in {0, 1}; ``distance`` float32 (B, Hp, Wp) metres;
    ``valid`` bool (B, Hp, Wp); ``index`` int64 (B,) dataset indices.

    Args:
      reader: a :class:`gijax.data.reader.DatasetReader` (or anything with ``len`` and
        ``__getitem__`` returning its sample dicts).
      rig: the rig used for the surrogate resampling (default: ``reader.rig``).
      batch_size: samples per batch on this process.
      seed: drives shuffling and mask augmentation.
      surrogate: the surrogate panorama (the paper's 512 x 2048 hemisphere by default).
      shuffle: permute samples every epoch (else dataset order).
      mask_augmentation: the paper's random rectangle erased from one camera's mask per sample.
      augment: photometric / body-outline augmentation of every sample's fisheyes
        (:func:`gijax.data.augment.augment_sample`), drawn from ``(seed, epoch, index)``;
        None (or a config that is all off) leaves the images alone. For training only.
      workers: loader threads (0 loads in the calling thread).
      pool: an executor to load in instead of the loader's own threads (``workers`` is then
        ignored), shared by several loaders so that a mixture of datasets does not start
        threads per dataset; its owner shuts it down, :meth:`close` only cancels this
        loader's pending loads.
      process_index, process_count: this process's shard for multi-host training.
      state: a :meth:`state` to resume from.
      drop_last: drop the incomplete last batch of an epoch (keeps shapes static).
      prefetch: batches loaded ahead.
      num_epochs: stop after this many epochs (None: run forever).
      use_sample_masks: per-sample masks from the data (default) or the rig's static masks.
    """

    def __init__(self, reader, rig: Rig | None = None, batch_size: int = 16, seed: int = 0,
                 surrogate: Panorama = Panorama.hemisphere(512, 2048), shuffle: bool = True,
                 mask_augmentation: bool = False, workers: int = 2, process_index: int = 0,
                 process_count: int = 1, state: dict | None = None, drop_last: bool = True,
                 prefetch: int = 2, num_epochs: int | None = None,
                 use_sample_masks: bool = True, augment: AugmentConfig | None = None,
                 pool: concurrent.futures.Executor | None = None):
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1; found {batch_size}")
        if not 0 <= process_index < process_count:
            raise ValueError(f"process_index must be in [0, process_count={process_count}); "
                             f"found {process_index}")
        self.reader = reader
        self.rig = reader.rig if rig is None else rig
        self.batch_size = int(batch_size)
        self.seed = int(seed)
        self.surrogate = surrogate
        self.shuffle = bool(shuffle)
        self.mask_augmentation = bool(mask_augmentation)
        self.augment = None if augment is None or augment.is_identity() else augment
        self.workers = int(workers)
        self.process_index = int(process_index)
        self.process_count = int(process_count)
        self.drop_last = bool(drop_last)
        self.prefetch = max(1, int(prefetch))
        self.num_epochs = num_epochs
        self.use_sample_masks = use_sample_masks
        self.num_samples = len(reader)
        self.shard_size = self.num_samples // self.process_count
        if self.drop_last:
            self.batches_per_epoch = self.shard_size // self.batch_size
        else:
            self.batches_per_epoch = math.ceil(self.shard_size / self.batch_size)
        if self.batches_per_epoch == 0:
            raise ValueError(f"{self.num_samples} samples over {self.process_count} process(es) "
                             f"give {self.shard_size} per process, fewer than batch_size "
                             f"{self.batch_size}")
        self._epoch, self._position = 0, 0
        if state is not None:
            self._restore(state)
        self._cursor = (self._epoch, self._position)
        self._pending: collections.deque = collections.deque()
        self._orders: dict[int, np.ndarray] = {}
        self._grids = None
        if is_homogeneous(self.rig):
            self._grids = surrogate_maps(self.rig, surrogate)
        self._owns_pool = pool is None
        if pool is None and self.workers > 0:
            pool = concurrent.futures.ThreadPoolExecutor(self.workers, "gijax-loader")
        self._pool = pool

    # -- state

    def _settings(self) -> dict:
        return {k: getattr(self, k) for k in _STATE_KEYS}

    def state(self) -> dict:
        """Where the stream stands: the epoch and batch position of the next batch."""
        return {"epoch": self._epoch, "position": self._position, **self._settings()}

    def _restore(self, state: dict) -> None:
        mine = self._settings()
        for k in _STATE_KEYS:
            if k in state and state[k] != mine[k]:
                raise ValueError(f"loader state was saved with {k}={state[k]!r}, but this loader "
                                 f"has {k}={mine[k]!r}")
        epoch, position = int(state["epoch"]), int(state["position"])
        if not 0 <= position <= self.batches_per_epoch or epoch < 0:
            raise ValueError(f"loader state position {position} (epoch {epoch}) is outside "
                             f"0..{self.batches_per_epoch}")
        if position == self.batches_per_epoch:
            epoch, position = epoch + 1, 0
        self._epoch, self._position = epoch, position

    # -- order

    def epoch_indices(self, epoch: int) -> np.ndarray:
        """This process's sample indices for ``epoch``, in batch order."""
        if epoch not in self._orders:
            order = epoch_order(self.num_samples, self.seed, epoch, self.shuffle)
            self._orders = {epoch: shard_order(order, self.process_index, self.process_count)}
        return self._orders[epoch]

    def batch_indices(self, epoch: int, position: int) -> np.ndarray:
        idx = self.epoch_indices(epoch)
        return idx[position * self.batch_size:(position + 1) * self.batch_size]

    def __len__(self) -> int:
        """Batches per epoch on this process."""
        return self.batches_per_epoch

    # -- loading

    def load_example(self, index: int, epoch: int) -> dict:
        """One sample as the model consumes it: surrogates, surrogate masks and the label."""
        sample = self.reader[int(index)]
        images = [np.asarray(im, np.float32) / np.float32(255.0) for im in sample["images"]]
        if self.use_sample_masks:
            masks = [np.asarray(m, np.float32) for m in sample["masks"]]
        else:
            masks = [np.ones((c.height, c.width), np.float32) if m is None
                     else np.asarray(m, np.float32) for c, m in zip(self.rig.cameras,
                                                                    self.rig.masks)]
        if self.mask_augmentation:
            images, masks, _ = augment_masks(images, masks,
                                             host_rng(self.seed, "erase", epoch, int(index)))
        if self.augment is not None:
            images, masks = self._augment_pixels(images, masks, int(index), epoch)
        if self._grids is not None:
            sur, smask = _resample(*self._grids, jnp.asarray(np.stack(images)),
                                             jnp.asarray(np.stack(masks)))
        elif len({m.shape for m in masks}) == 1:  # mixed camera models, one image size
            sur, smask = surrogate_images(self.rig, jnp.asarray(np.stack(images)),
                                          jnp.asarray(np.stack(masks)), self.surrogate)
        else:  # cameras of different sizes: one camera at a time
            outs = [_surrogate_one(cam, jnp.asarray(im), jnp.asarray(m), self.surrogate)
                    for cam, im, m in zip(self.rig.cameras, images, masks)]
            sur, smask = np.stack([o[0] for o in outs]), np.stack([o[1] for o in outs])
        distance = np.asarray(sample["pano_distance"], np.float32)
        return {"surrogates": np.asarray(sur, np.float32),
                "masks": np.asarray(smask, np.float32),
                "distance": distance, "valid": usable_label(distance), "index": int(index)}

    def _augment_pixels(self, images, masks, index: int, epoch: int):
        key = device_key(self.seed, "pixels", epoch, index)
        centres = np.array([[float(c.cx), float(c.cy)] for c in self.rig.cameras], np.float32)
        if len({m.shape for m in masks}) == 1:
            out_i, out_m = _augment(key, np.stack(images), np.stack(masks), self.augment, centres)
            return list(np.asarray(out_i)), list(np.asarray(out_m))
        # Cameras of different sizes: one camera at a time, each on its own sub-key.
        outs = [_augment(jax.random.fold_in(key, i), im[None], m[None], self.augment,
                         centres[i:i + 1]) for i, (im, m) in enumerate(zip(images, masks))]
        return [np.asarray(o[0][0]) for o in outs], [np.asarray(o[1][0]) for o in outs]

    def _schedule(self) -> None:
        while len(self._pending) < self.prefetch:
            epoch, position = self._cursor
            if self.num_epochs is not None and epoch >= self.num_epochs:
                return
            idx = self.batch_indices(epoch, position)
            if self._pool is None:
                jobs = [(self.load_example, i, epoch) for i in idx]
            else:
                jobs = [self._pool.submit(self.load_example, int(i), epoch) for i in idx]
            self._pending.append(jobs)
            position += 1
            if position == self.batches_per_epoch:
                epoch, position = epoch + 1, 0
            self._cursor = (epoch, position)

    def __iter__(self) -> Iterator[dict]:
        return self

    def __next__(self) -> dict:
        self._schedule()
        if not self._pending:
            raise StopIteration
        jobs = self._pending.popleft()
        if self._pool is None:
            examples = [fn(i, e) for fn, i, e in jobs]
        else:
            examples = [job.result() for job in jobs]
        batch = {k: np.stack([ex[k] for ex in examples]) for k in examples[0]}
        self._position += 1
        if self._position == self.batches_per_epoch:
            self._epoch, self._position = self._epoch + 1, 0
        self._schedule()
        return batch

    def close(self) -> None:
        """Stop the worker threads (pending loads are cancelled)."""
        if self._pool is not None:
            if self._owns_pool:
                self._pool.shutdown(wait=True, cancel_futures=True)
            else:
                for jobs in self._pending:
                    for job in jobs:
                        job.cancel()
                concurrent.futures.wait([j for jobs in self._pending for j in jobs])
            self._pool = None
        self._pending.clear()

    def __enter__(self) -> "Loader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
