"""Crash-safe, resumable dataset writer (layout in :mod:`gijax.data.format`).

Each sample's files are written to temporary names and renamed; only then is its row added to
the trajectory CSV (rewritten atomically) and, when the trajectory is new, the manifest
(rewritten atomically after the CSV). A crash therefore leaves at worst renamed files that no
CSV row points at, which a later run overwrites. Opening an existing dataset checks that it
was made for the same rig, panorama and generator settings, and continues after its last
committed sample; PNG encoding and JSON/CSV output are deterministic, so an interrupted and
resumed run produces the same bytes as an uninterrupted one.

A writer holds the folder's lock (:mod:`gijax.io.lock`) from opening to :meth:`close`, so a
second writer of the same folder fails at once, naming the first one's PID. The manifest
records how many samples were requested (:meth:`DatasetWriter.request`), so a dataset whose
writer was interrupted reads as incomplete rather than as a smaller complete one.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, Iterable, Mapping

import numpy as np

from gijax.data import format as fmt
from gijax.data import pngio
from gijax.geometry.panorama import Panorama
from gijax.io.lock import LOCK_FILE, FolderLock
from gijax.io.paths import write_bytes_atomic
from gijax.io.rigfile import save_rig
from gijax.geometry.rig import Rig


def _comparable(doc):
    """JSON round trip, so that tuples and lists compare equal."""
    return json.loads(json.dumps(doc))


class DatasetWriter:
    """Append samples (dicts like ``gijax.render.render_sample`` returns) to a dataset folder.

    Args:
      root: dataset folder (created when missing).
      rig: the rig the samples were rendered with; stored in rig/rig.yaml and its masks.
      pano: the ground-truth panorama of ``pano_distance``.
      trajectory_size: samples per trajectory folder.
      generator: settings that determine the samples' content (e.g. the render command's
        seed and style); a resumed run must pass the same settings.
      distance_range: (d_min, d_max) metres recorded in the metadata.
      durable: fsync every file before its rename (survives power loss, not only crashes).

    The writer locks ``root`` until :meth:`close` (or the end of a ``with`` block, or of the
    process); opening a folder another process is writing raises
    :class:`gijax.io.lock.FolderLockedError`.
    """

    def __init__(self, root, rig: Rig, pano: Panorama = Panorama.hemisphere(160, 640), *,
                 trajectory_size: int = fmt.DEFAULT_TRAJECTORY_SIZE,
                 generator: Mapping | None = None,
                 distance_range=fmt.DEFAULT_DISTANCE_RANGE, durable: bool = False):
        if trajectory_size < 1:
            raise ValueError(f"trajectory_size must be >= 1; found {trajectory_size}")
        fmt.check_names(rig.names)
        self.root = Path(root)
        self.rig = rig
        self.pano = pano
        self.names = list(rig.names)
        self.durable = durable
        self.generator = None if generator is None else _comparable(dict(generator))
        self.meta = fmt.metadata_doc(pano, distance_range)
        self.requested: int | None = None
        self.root.mkdir(parents=True, exist_ok=True)
        self._lock = FolderLock(self.root, "dataset").acquire()
        try:
            if (self.root / fmt.MANIFEST).exists():
                self._resume(trajectory_size)
            else:
                self.trajectory_size = int(trajectory_size)
                self._create()
        except BaseException:
            self._lock.release()
            raise

    def close(self) -> None:
        """Release the folder (the samples written are committed already)."""
        self._lock.release()

    def __enter__(self) -> "DatasetWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- opening

    def _create(self) -> None:
        self.root.mkdir(parents=True, exist_ok=True)
        if any(p.name not in (".gitkeep", LOCK_FILE) for p in self.root.iterdir()):
            stray = sorted(p.name for p in self.root.iterdir())[:5]
            raise ValueError(f"{self.root} is not empty and has no {fmt.MANIFEST}; refusing to "
                             f"write a dataset there (found {stray})")
        # The rig, stored once: the rig file and its mask PNGs.
        save_rig(self.rig, self.root / fmt.RIG_FILE)
        self._write(self.root / fmt.METADATA, fmt.dumps(self.meta))
        self.trajectories: list[str] = []
        self.rows: list[dict] = []
        # The manifest is written last: its presence marks the folder as a dataset.
        self._write_manifest()

    def _resume(self, trajectory_size: int) -> None:
        manifest = fmt.read_manifest(self.root)
        path = self.root / fmt.MANIFEST
        if manifest.get("format") != fmt.FORMAT_NAME:
            raise ValueError(f"{path}: format {manifest.get('format')!r} is not "
                             f"{fmt.FORMAT_NAME!r}; cannot append to it")
        self.version = fmt.manifest_version(manifest, path)
        metadata = fmt.load_json(self.root / fmt.METADATA, fmt.METADATA)
        found = metadata
        if self.version == 1:
            # Version 1 also kept the rig's cameras and occluder here (compared below, through
            # the rig); the rest must match like a current dataset's.
            found = {k: v for k, v in found.items() if k not in ("cameras", "occluder")}
        want = _comparable(self.meta)
        if found != want:
            diff = sorted(k for k in set(found) | set(want) if found.get(k) != want.get(k))
            raise ValueError(f"{self.root / fmt.METADATA} differs from the panorama being "
                             f"written (fields {diff}); use a new output folder")
        # Masks are stored binary (>= 0.5 is valid): compare the rig as it was stored.
        stored = self.rig.replace(masks=tuple(
            None if m is None else (np.asarray(m) >= 0.5).astype(np.float32)
            for m in self.rig.masks))
        diff = fmt.rig_differences(fmt.read_rig(self.root, manifest, metadata), stored)
        if diff:
            raise ValueError(f"{self.root / fmt.RIG_FILE} differs from the rig being written "
                             f"({'; '.join(diff)}); use a new output folder")
        old_gen = manifest.get("generator")
        if old_gen != self.generator:
            raise ValueError(f"{path}: the dataset was made with generator settings {old_gen}, "
                             f"not {self.generator}; use the same settings or a new folder")
        self.trajectory_size = int(manifest.get("trajectory_size", trajectory_size))
        self.requested = fmt.requested_samples(manifest, path)
        self.trajectories = [t["name"] for t in manifest["trajectories"]]
        for k, t in enumerate(self.trajectories):
            if t != fmt.trajectory_name(k):
                raise ValueError(f"{path}: trajectory {k} is named {t!r}, expected "
                                 f"{fmt.trajectory_name(k)!r}; cannot append")
        self.rows = []
        if self.trajectories:
            last = self.trajectories[-1]
            csv_path = self.root / last / fmt.FILE_LIST
            self.rows = fmt.read_file_list(csv_path, self.names)
            for k, row in enumerate(self.rows):
                if int(row["frame"]) != k:
                    raise ValueError(f"{csv_path} line {row['_line']}: frame {row['frame']} "
                                     f"out of order (expected {k}); cannot append")
            self._clean_partials(self.root / last)
            self._clean_partials(self.root / fmt.trajectory_name(len(self.trajectories)))

    def _clean_partials(self, folder: Path) -> None:
        """Remove temporary files an interrupted run left behind (never complete files)."""
        if not folder.is_dir():
            return
        for p in folder.rglob(f"*{pngio.PARTIAL_SUFFIX}"):
            p.unlink()

    # -- writing

    def _write(self, path: Path, data: bytes) -> None:
        write_bytes_atomic(path, data, suffix=pngio.PARTIAL_SUFFIX, fsync=self.durable)

    def _require_current(self) -> None:
        """A dataset of an older format is read and confirmed, never appended to."""
        if getattr(self, "version", fmt.FORMAT_VERSION) != fmt.FORMAT_VERSION:
            raise ValueError(f"{self.root / fmt.MANIFEST}: format version {self.version} (the "
                             f"rig stored in several documents); this gijax appends only to "
                             f"version {fmt.FORMAT_VERSION} datasets; use a new output folder")

    def _write_manifest(self) -> None:
        self._require_current()
        doc = fmt.manifest_doc(self.trajectories, self.trajectory_size, self.generator,
                               self.requested)
        self._write(self.root / fmt.MANIFEST, fmt.dumps(doc))

    @property
    def num_committed(self) -> int:
        """Samples already in the dataset (rows in the manifest's file lists)."""
        if not self.trajectories:
            return 0
        return (len(self.trajectories) - 1) * self.trajectory_size + len(self.rows)

    def request(self, total: int) -> None:
        """Record that the dataset is to hold ``total`` samples (at least those it holds), before
        writing them: readers then know a dataset whose writer stopped early is incomplete.
        Asking for what it already holds marks an interrupted dataset as complete as it is."""
        if total < 0:
            raise ValueError(f"requested sample count must be >= 0; found {total}")
        total = max(int(total), self.num_committed)
        if total != self.requested:
            self.requested = total
            self._write_manifest()

    def _check_sample(self, sample: Mapping) -> None:
        for key in ("images", "distances", "masks", "pano_distance"):
            if key not in sample:
                raise ValueError(f"sample lacks {key!r}; expected images, distances, masks, "
                                 f"pano_distance")
        n = len(self.names)
        for key in ("images", "distances", "masks"):
            if len(sample[key]) != n:
                raise ValueError(f"sample {key!r} has {len(sample[key])} cameras; the rig has {n}")
        for c, cam in enumerate(self.rig.cameras):
            hw = (cam.height, cam.width)
            for key, shape, dtype in (("images", hw + (3,), np.uint8),
                                      ("distances", hw, np.float32), ("masks", hw, np.uint8)):
                a = np.asarray(sample[key][c])
                if a.shape != shape or a.dtype != dtype:
                    raise ValueError(f"sample {key}[{c}] ({self.names[c]}) must be {dtype.__name__}"
                                     f" {shape}; found {a.dtype} {a.shape}")
            if not np.all(np.isfinite(sample["distances"][c])):
                raise ValueError(f"sample distances[{c}] ({self.names[c]}) has non-finite values")
            if np.asarray(sample["masks"][c]).max(initial=0) > 1:
                raise ValueError(f"sample masks[{c}] ({self.names[c]}) must hold 0/1 values")
        pd = np.asarray(sample["pano_distance"])
        if pd.shape != self.pano.shape or pd.dtype != np.float32:
            raise ValueError(f"sample pano_distance must be float32 {self.pano.shape}; found "
                             f"{pd.dtype} {pd.shape}")
        if not np.all(np.isfinite(pd)):
            raise ValueError("sample pano_distance has non-finite values")

    def write(self, sample: Mapping, seed: int | None = None) -> int:
        """Write and commit one sample; returns its index. ``seed`` is recorded in the CSV."""
        if not self._lock.held:
            raise ValueError(f"dataset writer of {self.root} is closed")
        self._require_current()
        self._check_sample(sample)
        index = self.num_committed
        t, frame = divmod(index, self.trajectory_size)
        traj = fmt.trajectory_name(t)
        folder = self.root / traj
        files = fmt.sample_files(self.names, frame)
        for name in self.names:
            for kind in fmt.CAMERA_KINDS:
                (folder / name / kind).mkdir(parents=True, exist_ok=True)
        (folder / fmt.PANO_FRAME / "distance").mkdir(parents=True, exist_ok=True)
        for c, name in enumerate(self.names):
            self._write(folder / files[f"{name}_rgb"],
                        pngio.encode_rgb(np.asarray(sample["images"][c])))
            self._write(folder / files[f"{name}_distance"],
                        pngio.encode_distance(np.asarray(sample["distances"][c])))
            self._write(folder / files[f"{name}_mask"],
                        pngio.encode_mask(np.asarray(sample["masks"][c])))
        self._write(folder / files[f"{fmt.PANO_FRAME}_distance"],
                    pngio.encode_distance(np.asarray(sample["pano_distance"])))
        new_traj = frame == 0
        rows = [] if new_traj else self.rows
        rows = rows + [{"frame": str(frame), "seed": "" if seed is None else str(int(seed)),
                        **files}]
        # Commit: the CSV row only now that every file exists, then the manifest that lists it.
        self._write(folder / fmt.FILE_LIST, fmt.file_list_bytes(self.names, rows))
        self.rows = rows
        if new_traj:
            self.trajectories.append(traj)
            self._write_manifest()
        return index


def write_dataset(root, samples: Callable[[int], Mapping] | Iterable[Mapping], rig: Rig,
                  pano: Panorama = Panorama.hemisphere(160, 640), *,
                  num_samples: int | None = None, seeds: Callable[[int], int] | None = None,
                  progress: Callable[[int, int], None] | None = None, **writer_kw) -> int:
    """Write samples to ``root``, resuming after the samples it already holds.

    ``samples`` is either a function ``i -> sample`` (then ``num_samples`` is the target total;
    already committed indices are not recomputed) or an iterable of samples (already committed
    ones are consumed and dropped). ``seeds(i)`` gives the seed recorded for sample i.
    ``progress(done, total)`` is called after each commit. Returns the number of samples written
    by this call.
    """
    if callable(samples) and num_samples is None:
        raise ValueError("num_samples is required when samples is a function")
    with DatasetWriter(root, rig, pano, **writer_kw) as writer:
        start = writer.num_committed
        if num_samples is not None:
            writer.request(num_samples)
        written = 0
        if callable(samples):
            for i in range(start, num_samples):
                writer.write(samples(i), None if seeds is None else seeds(i))
                written += 1
                if progress is not None:
                    progress(i + 1, num_samples)
            return written
        for i, sample in enumerate(samples):
            if num_samples is not None and i >= num_samples:
                break
            if i < start:
                continue
            writer.write(sample, None if seeds is None else seeds(i))
            written += 1
            if progress is not None:
                progress(i + 1, num_samples or 0)
        return written


def sample_seed(seed: int, index: int) -> int:
    """The render seed of sample ``index`` of a dataset generated with ``seed`` (31-bit)."""
    state = np.random.SeedSequence([int(seed), int(index)]).generate_state(1, np.uint32)[0]
    return int(state >> 1)


__all__ = ["DatasetWriter", "write_dataset", "sample_seed"]
