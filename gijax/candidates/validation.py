"""Argument checks shared by the candidate functions and every consumer of a candidate list.

Two regimes, one rule each:

* Concrete values (plain Python / NumPy / JAX arrays outside any transformation) are checked
  eagerly and a bad value raises ``ValueError`` naming the argument, what was expected and what
  was found.
* Traced values (inside ``jit``, ``vmap`` or ``grad``) have no value to inspect. Shape checks
  still raise (shapes are static); value checks become ``jax.experimental.checkify`` debug
  checks: a no-op in plain ``jit``, an error under ``checkify.checkify(fn)``. Functions that
  can detect a degenerate result (a rig without coverage) return NaN there as well.
"""

from __future__ import annotations

import math
import numbers

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import checkify


def is_concrete(*trees) -> bool:
    """True when every leaf of ``trees`` has a known value (none is a tracer)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(trees))


def require(ok, message: str, inputs=(), **values) -> None:
    """``ValueError(message.format(**values))`` when ``ok`` is False and ``ok``, ``values`` and
    ``inputs`` are all concrete; a checkify debug check of ``ok`` otherwise.

    ``values`` are arrays (or numbers) formatted into ``message`` with ``str.format`` fields.
    ``inputs`` are the arguments ``ok`` was computed from: a predicate can come back concrete
    from a traced computation (a value with no dependence on the traced arguments), and the
    function must then still behave as under a trace.
    """
    if is_concrete(ok, values, inputs):
        if not bool(np.all(np.asarray(ok))):
            raise ValueError(message.format(**{k: _plain(v) for k, v in values.items()}))
        return
    checkify.debug_check(jnp.all(jnp.asarray(ok)), message,
                         **{k: jnp.asarray(v) for k, v in values.items()})


def _plain(v):
    a = np.asarray(v)
    return a.item() if a.ndim == 0 else a.tolist()


def check_count(n) -> int:
    """``n`` must be an integer >= 2 (a list needs both ends of the range); it sets a shape, so
    it must be a Python integer even under a trace."""
    if isinstance(n, bool) or not isinstance(n, (numbers.Integral, np.integer)):
        raise ValueError(f"n must be an integer >= 2; found {n!r}")
    if n < 2:
        raise ValueError(f"n must be >= 2 (the list holds d_min and d_max); found n={n}")
    return int(n)


def check_range(d_min, d_max) -> None:
    """0 < d_min < d_max, both finite (metres); a debug check when either is traced."""
    if not is_concrete(d_min, d_max):
        lo, hi = jnp.asarray(d_min), jnp.asarray(d_max)
        require((lo > 0) & (lo < hi) & jnp.isfinite(hi),
                "need 0 < d_min < d_max < inf (metres); found d_min={lo}, d_max={hi}", lo=lo,
                hi=hi)
        return
    lo, hi = float(d_min), float(d_max)
    if not (math.isfinite(lo) and lo > 0.0):
        raise ValueError(f"d_min must be a finite distance > 0 m; found d_min={lo}")
    if not math.isfinite(hi):
        raise ValueError(f"d_max must be a finite distance in metres; found d_max={hi}")
    if not lo < hi:
        raise ValueError(f"d_min must be smaller than d_max; found d_min={lo}, d_max={hi}")


def check_baseline(baseline) -> None:
    """The closed form needs a finite baseline > 0 (metres); a debug check when traced."""
    if not is_concrete(baseline):
        b = jnp.asarray(baseline)
        require(jnp.isfinite(b) & (b > 0.0), "baseline must be a finite length > 0 m; found "
                "baseline={b}", b=b)
        return
    b = float(baseline)
    if not (math.isfinite(b) and b > 0.0):
        raise ValueError(f"baseline must be a finite length > 0 m; found baseline={b}")


def check_candidates(candidates, what: str = "candidates", count: int | None = None,
                     min_count: int = 2) -> np.ndarray:
    """The one eager check of a candidate list: a 1-D array of finite distances > 0 m, strictly
    ascending, with ``count`` entries (or at least ``min_count``).

    Returns the list as a float64 NumPy array; raises ``ValueError`` naming ``what`` and the
    problem. Concrete values only (a traced list has no values to check: see
    :func:`guard_candidates`).
    """
    if not is_concrete(candidates):
        raise ValueError(f"{what}: check_candidates needs concrete values, not a traced array "
                         "(use guard_candidates inside jit / vmap / grad)")
    c = np.asarray(candidates, np.float64)
    _check_candidate_shape(c.shape, what, count, min_count)
    if not np.all(np.isfinite(c)):
        raise ValueError(f"{what} must be finite distances in metres; found {c.tolist()}")
    if np.any(c <= 0.0):
        raise ValueError(f"{what} must be distances > 0 m; found {c.tolist()}")
    if np.any(np.diff(c) <= 0.0):
        raise ValueError(f"{what} must be strictly ascending distances; found {c.tolist()}")
    return c


def guard_candidates(candidates, what: str = "candidates", count: int | None = None,
                     min_count: int = 2) -> None:
    """:func:`check_candidates` for concrete values; under a trace the shape is checked (it is
    static) and the values become a checkify debug check."""
    if is_concrete(candidates):
        check_candidates(candidates, what, count, min_count)
        return
    _check_candidate_shape(tuple(candidates.shape), what, count, min_count)
    c = jnp.asarray(candidates)
    require(jnp.all(jnp.isfinite(c)) & jnp.all(c > 0) & jnp.all(jnp.diff(c) > 0),
            what + " must be finite, > 0 m and strictly ascending; found {c}", c=c)


def _check_candidate_shape(shape, what: str, count: int | None, min_count: int) -> None:
    if len(shape) != 1:
        raise ValueError(f"{what} must be a 1-D list of distances; found shape {tuple(shape)}")
    if count is not None and shape[0] != count:
        raise ValueError(f"{what} must hold {count} distances; found {shape[0]}")
    if shape[0] < min_count:
        raise ValueError(f"{what} must hold at least {min_count} distances; found {shape[0]}")
