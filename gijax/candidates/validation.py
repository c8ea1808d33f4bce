"""Argument checks shared by the candidate functions.

They run on concrete Python/NumPy values, outside any trace: a traced value (the function is
being jitted or differentiated) is passed through unchecked, because its value is unknown.
"""

from __future__ import annotations

import math
import numbers

import jax
import numpy as np


def is_concrete(x) -> bool:
    """True when ``x`` has a known value (not a tracer inside jit/grad/vmap)."""
    return not isinstance(x, jax.core.Tracer)


def check_count(n) -> int:
    """``n`` must be an integer >= 2 (a list needs both ends of the range)."""
    if isinstance(n, bool) or not isinstance(n, (numbers.Integral, np.integer)):
        raise ValueError(f"n must be an integer >= 2; found {n!r}")
    if n < 2:
        raise ValueError(f"n must be >= 2 (the list holds d_min and d_max); found n={n}")
    return int(n)


def check_range(d_min, d_max) -> None:
    """0 < d_min < d_max, both finite (metres); traced values pass unchecked."""
    lo = float(d_min) if is_concrete(d_min) else None
    hi = float(d_max) if is_concrete(d_max) else None
    if lo is not None and not (math.isfinite(lo) and lo > 0.0):
        raise ValueError(f"d_min must be a finite distance > 0 m; found d_min={lo}")
    if hi is not None and not math.isfinite(hi):
        raise ValueError(f"d_max must be a finite distance in metres; found d_max={hi}")
    if lo is not None and hi is not None and not lo < hi:
        raise ValueError(f"d_min must be smaller than d_max; found d_min={lo}, d_max={hi}")


def check_baseline(baseline) -> None:
    """The closed form needs a finite baseline > 0 (metres)."""
    if is_concrete(baseline):
        b = float(baseline)
        if not (math.isfinite(b) and b > 0.0):
            raise ValueError(f"baseline must be a finite length > 0 m; found baseline={b}")
