"""Wall-clock timing with warm-up, repetitions, robust statistics and alternating comparisons.

Every timed call is followed by ``block_until_ready`` on its result (JAX dispatches
asynchronously; without it the clock would stop before the device finished). Statistics are the
median and the inter-quartile range (IQR, 25th to 75th percentile, linear interpolation) with
the minimum and maximum: the median resists other processes stealing the CPU now and then,
the IQR says how much they did.

Two things compared (JAX vs onnxruntime, 3 vs 4 cameras) are timed in the same run with
alternating repetitions: round ``i`` runs every contender once, in an order rotated by ``i``, so
slow phases of a shared machine hit all contenders alike; ratios are taken per round.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from typing import Callable, Mapping, Sequence

import numpy as np


def block(result):
    """Wait for every array in ``result`` (any pytree) to be computed; returns ``result``."""
    if "jax" not in sys.modules:
        # No JAX array can exist in a process that never imported JAX (an onnxruntime
        # measurement must not import it just to find that out).
        return result
    import jax

    for leaf in jax.tree_util.tree_leaves(result):
        wait = getattr(leaf, "block_until_ready", None)
        if wait is not None:
            wait()
    return result


@dataclasses.dataclass(frozen=True)
class Stats:
    """Summary of repeated measurements (same unit as the samples, seconds for times)."""

    n: int
    median: float
    q1: float
    q3: float
    min: float
    max: float
    mean: float

    @property
    def iqr(self) -> float:
        return self.q3 - self.q1

    def scaled(self, factor: float) -> "Stats":
        """The same statistics times ``factor`` (e.g. 1e3 for milliseconds)."""
        return Stats(self.n, *(factor * v for v in (self.median, self.q1, self.q3, self.min,
                                                    self.max, self.mean)))

    def as_dict(self, prefix: str = "", factor: float = 1.0) -> dict:
        s = self.scaled(factor)
        return {f"{prefix}median": s.median, f"{prefix}q1": s.q1, f"{prefix}q3": s.q3,
                f"{prefix}iqr": s.iqr, f"{prefix}min": s.min, f"{prefix}max": s.max,
                f"{prefix}mean": s.mean, f"{prefix}n": s.n}


def timing_stats(samples: Sequence[float]) -> Stats:
    """Median, quartiles, min, max and mean of ``samples`` (at least one finite value)."""
    x = np.asarray(samples, np.float64).reshape(-1)
    if x.size == 0:
        raise ValueError("timing_stats needs at least one sample; found none")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"samples must be finite; found {x.tolist()}")
    q1, med, q3 = np.percentile(x, [25.0, 50.0, 75.0])
    return Stats(int(x.size), float(med), float(q1), float(q3), float(x.min()), float(x.max()),
                 float(x.mean()))


def _check_counts(warmup: int, reps: int) -> None:
    if int(warmup) != warmup or warmup < 0:
        raise ValueError(f"warmup must be a non-negative integer; found {warmup!r}")
    if int(reps) != reps or reps < 1:
        raise ValueError(f"reps must be a positive integer; found {reps!r}")


def time_call(fn: Callable[[], object], *, warmup: int = 1, reps: int = 5,
              timer: Callable[[], float] = time.perf_counter) -> tuple[Stats, list[float]]:
    """Time ``fn()`` (blocking on its result): ``warmup`` untimed calls, then ``reps`` timed.

    Returns the statistics and the list of the timed durations, seconds.
    """
    _check_counts(warmup, reps)
    for _ in range(warmup):
        block(fn())
    times = []
    for _ in range(reps):
        t0 = timer()
        block(fn())
        times.append(timer() - t0)
    return timing_stats(times), times


def time_alternating(fns: Mapping[str, Callable[[], object]], *, warmup: int = 1, reps: int = 5,
                     timer: Callable[[], float] = time.perf_counter) -> dict[str, list[float]]:
    """Time several contenders in interleaved rounds; returns name -> durations (seconds).

    Warm-up calls run each contender ``warmup`` times first. Round ``i`` then calls every
    contender once, starting at contender ``i mod k``, so the position in the round (the
    first call after another program may find colder caches) is shared out evenly.
    """
    _check_counts(warmup, reps)
    names = list(fns)
    if not names:
        raise ValueError("time_alternating needs at least one function; found none")
    for name in names:
        for _ in range(warmup):
            block(fns[name]())
    times: dict[str, list[float]] = {name: [] for name in names}
    for i in range(reps):
        k = i % len(names)
        for name in names[k:] + names[:k]:
            t0 = timer()
            block(fns[name]())
            times[name].append(timer() - t0)
    return times


def paired_ratio(numerator: Sequence[float], denominator: Sequence[float]) -> Stats:
    """Statistics of the per-round ratios ``numerator[i] / denominator[i]`` (same length)."""
    a = np.asarray(numerator, np.float64)
    b = np.asarray(denominator, np.float64)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"paired_ratio needs two 1-D sequences of equal length; found shapes "
                         f"{a.shape} and {b.shape}")
    if np.any(b <= 0):
        raise ValueError("paired_ratio: denominators must be positive durations")
    return timing_stats(a / b)


def linear_increment(counts: Sequence[float], values: Sequence[float]) -> dict:
    """Least-squares slope and intercept of ``values`` against ``counts`` (e.g. ms per camera),
    and the successive differences ``values[i+1] - values[i]`` per unit of count."""
    c = np.asarray(counts, np.float64)
    v = np.asarray(values, np.float64)
    if c.shape != v.shape or c.ndim != 1 or c.size < 2:
        raise ValueError(f"linear_increment needs two 1-D sequences of equal length >= 2; found "
                         f"shapes {c.shape} and {v.shape}")
    if np.unique(c).size != c.size:
        raise ValueError(f"linear_increment: counts must be distinct; found {c.tolist()}")
    order = np.argsort(c)
    c, v = c[order], v[order]
    slope, intercept = np.polyfit(c, v, 1)
    steps = np.diff(v) / np.diff(c)
    return {"slope": float(slope), "intercept": float(intercept), "steps": steps.tolist(),
            "counts": c.tolist()}
