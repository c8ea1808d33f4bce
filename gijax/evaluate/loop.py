"""The evaluation loop: a predictor over a dataset's batches -> per-scene and dataset metrics.

Every evaluation of gijax runs here: ``gijax eval``, the trainer's validation, the demo and the
experiments. The caller brings the batches (dicts with ``distance`` (B, H, W) metres and
whatever its predictor reads: surrogate images, indices into a reader, raw images) and a
function ``batch -> Prediction`` whose ``inv_distance`` and ``valid`` are (B, H, W). The
label of a pixel counts where it is usable (:func:`gijax.evaluate.labels.usable_label`) and,
when the batch has a ``valid`` entry, marked valid there.

How the metrics see pixels without an estimate (``valid`` False or a non-finite prediction;
the classical baseline leaves some) is ``holes``:

* ``'far'`` (``gijax eval``, the trainer): the definitions of :mod:`gijax.evaluate.metrics`:
  lost coverage, left out of MAE, RMSE and the bad-pixel rates; SSIM sees the prediction at
  the far end of the candidate range against the label.
* ``'unscored_far'`` (the experiments' tables): the same errors; SSIM sees the far end on both
  sides there, so a hole does not count against it.
* ``'unscored_mean'`` (the demo's table): the same errors; SSIM sees the mean of the
  estimated pixels on both sides.

With the two ``unscored`` choices the metrics' own ``coverage`` is 1 by construction; the
share of all usable label pixels with an estimate is :attr:`Evaluation.label_coverage`.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable, Iterable

import jax
import jax.numpy as jnp
import numpy as np

from gijax.evaluate.labels import usable_label
from gijax.evaluate.metrics import batch_sums, check_metric_set, summarize
from gijax.evaluate.prediction import Prediction

HOLES = ("far", "unscored_far", "unscored_mean")


@dataclasses.dataclass
class Evaluation:
    """What :func:`evaluate_predictions` found.

    ``metrics[set]`` the dataset metrics of each metric set (:func:`summarize`);
    ``sample_values[set]`` the per-sample values they were summarised from (arrays (N,));
    ``label_coverage`` the share of usable label pixels with an estimate; ``seconds`` the wall
    time of each predictor call divided by its batch size; ``examples`` the first samples'
    ``(prediction of one sample, label distance)``.
    """

    metrics: dict
    sample_values: dict
    label_coverage: float
    seconds: list
    examples: list

    @property
    def samples(self) -> int:
        return len(next(iter(self.sample_values.values()))["count"])

    def per_scene(self, metric_set: str) -> list[dict]:
        """The metrics of each sample on its own (as :func:`summarize` gives them)."""
        values = self.sample_values[metric_set]
        return [summarize({k: v[i:i + 1] for k, v in values.items()}, metric_set)
                for i in range(self.samples)]


def _scored_inputs(inv: np.ndarray, estimated: np.ndarray, label: np.ndarray, candidates,
                   holes: str):
    """(prediction, label mask, estimate mask or None) to hand to the metrics for ``holes``."""
    if holes == "far":
        return inv, label, estimated
    if holes == "unscored_far":
        fill = 1.0 / float(candidates[-1])
    else:
        fill = (np.nanmean(np.where(estimated, inv, np.asarray(np.nan, inv.dtype)))
                if estimated.any() else 0.0)
    return np.where(estimated, inv, fill).astype(np.float32), label & estimated, None


def evaluate_predictions(batches: Iterable[dict], predict: Callable[[dict], Prediction],
                         candidates, metric_sets=("paper",), holes: str = "far",
                         limit: int = 0, warmup: bool = False, keep: int = 0,
                         name: str = "evaluation data",
                         on_batch: Callable[[int], None] | None = None) -> Evaluation:
    """Metrics of ``predict`` over ``batches``.

    Args:
      batches: dicts with ``distance`` (B, H, W) metres, optionally ``valid`` (B, H, W), and
        what ``predict`` reads.
      predict: ``batch -> Prediction`` with ``inv_distance`` and ``valid`` (B, H, W).
      candidates: (D,) metres: the range the labels are clamped to and scored in.
      metric_sets: the definitions to compute, 'paper' and / or 'gijax'.
      holes: how pixels without an estimate are scored (module docstring).
      limit: stop once this many samples are evaluated (0: all; whole batches).
      warmup: call ``predict`` once on the first batch before timing (compilation).
      keep: how many of the first samples to return in ``examples``.
      name: the data's name in the error raised when there is no batch.
      on_batch: called with each batch's sample count once it is scored (a progress bar's
        ``update``: the loop itself draws nothing).
    """
    for m in metric_sets:
        check_metric_set(m)
    if holes not in HOLES:
        raise ValueError(f"holes must be one of {HOLES}; found {holes!r}")
    cand = jnp.asarray(candidates, jnp.float32)
    parts = {m: [] for m in metric_sets}
    seconds, examples = [], []
    covered = labelled = 0.0
    seen = 0
    for batch in batches:
        if limit and seen >= limit:
            break
        if warmup and seen == 0:              # compile outside the timing
            first = predict(batch)
            jax.block_until_ready((first.inv_distance, first.valid))
        t0 = time.perf_counter()
        pred = predict(batch)
        inv, est = jax.block_until_ready((pred.inv_distance, pred.valid))
        distance = np.asarray(batch["distance"])
        seconds.append((time.perf_counter() - t0) / len(distance))
        inv = np.asarray(inv)
        if inv.shape != distance.shape:
            raise ValueError(f"{name}: prediction {inv.shape} and label {distance.shape} "
                             f"panoramas differ")
        est = np.asarray(est, bool) & np.isfinite(inv)
        label = usable_label(distance)
        if "valid" in batch:
            label = label & np.asarray(batch["valid"], bool)
        covered += float(np.sum(label & est))
        labelled += float(np.sum(label))
        scored_inv, scored_label, scored_est = _scored_inputs(inv, est, label, candidates,
                                                              holes)
        for m in metric_sets:
            sums = batch_sums(jnp.asarray(scored_inv), jnp.asarray(distance),
                              jnp.asarray(scored_label), cand, metric_set=m,
                              pred_valid=None if scored_est is None else jnp.asarray(scored_est))
            parts[m].append(jax.tree.map(np.asarray, sums))
        for i in range(min(len(distance), keep - len(examples))):
            one = {k: (np.asarray(v)[i] if k in ("inv_distance", "valid", "distance", "entropy",
                                                  "prob", "colour") else v)
                   for k, v in pred.items()}
            examples.append((Prediction(**one), distance[i]))
        seen += len(distance)
        if on_batch is not None:
            on_batch(len(distance))
    if not seconds:
        raise ValueError(f"{name} yielded no samples")
    values = {m: {k: np.concatenate([p[k] for p in ps]) for k in ps[0]}
              for m, ps in parts.items()}
    return Evaluation(metrics={m: summarize(v, m) for m, v in values.items()},
                      sample_values=values, label_coverage=covered / max(labelled, 1.0),
                      seconds=seconds, examples=examples)
