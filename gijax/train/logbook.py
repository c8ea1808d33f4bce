"""A run's logbook: ``metrics.jsonl`` records, their TensorBoard scalars, validation sample
images, the learned candidate list and the progress bar.

Only process 0 writes; every process keeps the records it logged (``history``). One record per
step and split: a resumed run first drops what its killed predecessor logged after the
checkpoint it resumes from (:func:`drop_logs_after`).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from gijax.evaluate.labels import usable_label
from gijax.io.paths import write_png_atomic, write_text_atomic
from gijax.store.configs import METRICS_FILE

# The learned candidate list of a run with TrainConfig.learn_candidates (a --candidates FILE).
LEARNED_FILE = "candidates.json"


class Logbook:
    """The records of one run folder, written by process 0 (``is_main``)."""

    def __init__(self, run_dir: Path, is_main: bool, progress: bool):
        self.run_dir = Path(run_dir)
        self.is_main = is_main
        self.progress = progress
        self.history: list[dict] = []
        self._tb = None
        self._bar = None
        self._t_last = time.perf_counter()
        self._waited = 0.0

    def log(self, record: dict) -> None:
        """Append ``record`` to the history, ``metrics.jsonl`` and TensorBoard (its numbers,
        under its ``split``, ``train`` by default)."""
        self.history.append(record)
        if not self.is_main:
            return
        with open(self.run_dir / METRICS_FILE, "a") as f:
            f.write(json.dumps(record) + "\n")
        if self._tb is None:
            from gijax.io.events import EventWriter

            self._tb = EventWriter(self.run_dir / "tb")
        prefix = record.get("split", "train")
        self._tb.scalars(record["step"], {f"{prefix}/{k}": v for k, v in record.items()
                                          if isinstance(v, (int, float)) and k != "step"})
        self._tb.flush()

    def open(self, step: int, total: int, invocation: dict) -> None:
        """Start a piece of training at ``step`` of ``total``: drop records after ``step``,
        log the start or resume event with ``invocation``, show the progress bar."""
        if self.is_main:
            # A killed run may have logged steps after its last checkpoint (or before its
            # first one); they are computed and logged again from here.
            drop_logs_after(self.run_dir, step)
        if step > 0:
            self.log({"step": step, "event": "resumed", **invocation})
        elif invocation:
            self.log({"step": 0, "event": "started", **invocation})
        if self.progress and self.is_main:
            from tqdm import tqdm

            self._bar = tqdm(total=total, initial=step, unit="step", dynamic_ncols=True)
        self._t_last = time.perf_counter()
        # Host seconds spent getting batches since the last record. Steps are dispatched
        # asynchronously, so this overlaps the previous step's computation: it bounds from
        # above the time the step stood still for data, and grows towards the step time when
        # the loader falls behind.
        self._waited = 0.0

    def waited(self, seconds: float) -> None:
        """Count ``seconds`` the host spent getting a batch."""
        self._waited += seconds

    def advance(self) -> None:
        """One step done (the progress bar)."""
        if self._bar is not None:
            self._bar.update(1)

    def loss(self, step: int, out: dict, samples: int, lr: float) -> None:
        """Log the loss of ``step`` (``samples`` trained since the previous record); a
        non-finite loss raises FloatingPointError."""
        loss = float(out["loss"])
        if not math.isfinite(loss):
            raise FloatingPointError(f"training loss became {loss} at step {step}")
        now = time.perf_counter()
        elapsed = max(now - self._t_last, 1e-9)
        rate = samples / elapsed
        waited, self._waited = self._waited, 0.0
        self._t_last = now
        # A label-free objective's terms (``loss_photometric``, ...) beside their sum.
        terms = {k: float(v) for k, v in out.items() if k.startswith("loss_")}
        self.log({"step": step, "loss": loss, **terms, "grad_norm": float(out["grad_norm"]),
                  "lr": lr, "samples_per_s": rate,
                  "data_wait_fraction": min(waited / elapsed, 1.0)})
        if self._bar is not None:
            self._bar.set_postfix(loss=f"{loss:.4f}", samples_s=f"{rate:.2f}")

    def samples(self, step: int, samples, candidates) -> None:
        """Validation sample images: prediction above label, coloured over the inverse
        distances of ``candidates``, as PNGs under ``samples/`` and TensorBoard images."""
        if not self.is_main:
            return
        from gijax.viz.colormap import colorize

        lo, hi = 1.0 / float(candidates[-1]), 1.0 / float(candidates[0])
        folder = self.run_dir / "samples"
        folder.mkdir(exist_ok=True)
        for i, (inv, dist) in enumerate(samples):
            gt = 1.0 / np.where(usable_label(dist), dist, np.inf)
            gap = np.full((4, inv.shape[1], 3), 255, np.uint8)
            rgb = np.concatenate([colorize(inv, lo, hi), gap, colorize(gt, lo, hi)], axis=0)
            write_png_atomic(folder / f"step{step:07d}_sample{i}.png", rgb)
            if self._tb is not None:
                self._tb.image(step, f"val/prediction_above_label_below/{i}", rgb)

    def learned_candidates(self, step: int, current, initial) -> None:
        """candidates.json: the learned list now (and the list it started from)."""
        if not self.is_main:
            return
        doc = {"step": step, "candidates": np.asarray(current).tolist(),
               "initial": [float(c) for c in initial],
               "learned": True}
        write_text_atomic(self.run_dir / LEARNED_FILE, json.dumps(doc, indent=2))

    def lines(self) -> list[str]:
        """``metrics.jsonl`` as written so far (its lines, newlines kept)."""
        path = self.run_dir / METRICS_FILE
        return path.read_text().splitlines(keepends=True) if path.exists() else []

    def close(self) -> None:
        """End the piece: close the progress bar and the TensorBoard writer."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        if self._tb is not None:
            self._tb.close()
            self._tb = None


def drop_logs_after(run_dir, step: int) -> None:
    """Remove what ``metrics.jsonl`` and the TensorBoard files hold for steps after ``step``.

    A run killed between two checkpoints has logged steps that its resumed run computes (and
    logs) again from the last checkpoint; dropping them first keeps one record per step, so
    readers need no de-duplication. A line or event cut short by the kill goes too.
    """
    from gijax.io.events import drop_events_after

    run_dir = Path(run_dir)
    path = run_dir / METRICS_FILE
    if path.exists():
        kept = []
        for line in path.read_text().splitlines():
            try:
                record = json.loads(line)
            except ValueError:
                continue
            if isinstance(record, dict) and int(record.get("step", 0)) <= step:
                kept.append(line)
        write_text_atomic(path, "".join(line + "\n" for line in kept))
    for events in sorted((run_dir / "tb").glob("events.out.tfevents.*")):
        drop_events_after(events, step)
