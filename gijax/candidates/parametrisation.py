"""An unconstrained parametrisation of valid candidate lists, for optimising the list itself.

A valid list of N candidates runs strictly upward from ``d_min`` to ``d_max`` (both ends
included, as every list gijax makes does: EV, GI, the closed form at a camera spacing, rig-aware
GI). In inverse distance it runs down from ``1/d_min`` to ``1/d_max`` in N - 1 positive steps
whose sum is fixed. The steps are the softmax of N - 1 free numbers (``logits``) times that sum:

    q_0 = 1/d_min,   q_k = 1/d_min - (1/d_min - 1/d_max) * sum_{j<k} softmax(logits)_j,
    d_k = 1 / q_k,   so d_0 = d_min and d_{N-1} = d_max exactly.

Every real vector of logits is a valid list (no step of an optimiser can leave the set; in
floating point a step that underflows, a logit some 35 below the largest in float32, merges
two candidates, so keep the logits' spread well below that), equal
logits are the list even in inverse distance (EV), and :func:`logits_from_candidates` is the
inverse (the logs of the steps, centred: adding a constant to every logit changes nothing).
Both functions are traceable (jit, vmap, grad); the inverse checks a concrete list.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from gijax.candidates.validation import check_count, check_range, is_concrete

Array = jax.Array


def candidates_from_logits(logits: Array, d_min=0.5, d_max=100.0) -> Array:
    """(N,) ascending distances (m) from N - 1 logits; the ends are ``d_min`` and ``d_max``."""
    logits = jnp.asarray(logits)
    dtype = logits.dtype if jnp.issubdtype(logits.dtype, jnp.floating) else jnp.float32
    if logits.ndim != 1 or logits.shape[0] < 1:
        raise ValueError(f"candidate logits must have shape (N - 1,) with N >= 2; found "
                         f"{tuple(logits.shape)}")
    q_near = 1.0 / jnp.asarray(d_min, dtype)
    q_far = 1.0 / jnp.asarray(d_max, dtype)
    steps = jax.nn.softmax(logits.astype(dtype)) * (q_near - q_far)
    q = q_near - jnp.concatenate([jnp.zeros((1,), dtype), jnp.cumsum(steps)])
    # Rounding can leave the tail a hair past 1/d_max; the far end is exact by definition.
    q = jnp.maximum(q, q_far).at[-1].set(q_far)
    return 1.0 / q


def logits_from_candidates(candidates, d_min=None, d_max=None) -> Array:
    """The logits (N - 1,) of a list (N,) of ascending distances, centred to mean 0.

    ``d_min`` / ``d_max`` default to the list's ends; when given they must equal them (the
    parametrisation keeps the ends fixed). A concrete list must be strictly ascending
    (ValueError naming the first offending pair).
    """
    cand = jnp.asarray(candidates)
    dtype = cand.dtype if jnp.issubdtype(cand.dtype, jnp.floating) else jnp.float32
    cand = cand.astype(dtype)
    if cand.ndim != 1 or cand.shape[0] < 2:
        raise ValueError(f"a candidate list needs shape (N,) with N >= 2; found "
                         f"{tuple(cand.shape)}")
    if is_concrete(cand):
        c = np.asarray(cand, np.float64)
        check_count(len(c))
        bad = np.nonzero(np.diff(c) <= 0)[0]
        if len(bad) or not np.all(np.isfinite(c)) or c[0] <= 0:
            i = int(bad[0]) if len(bad) else 0
            raise ValueError(f"candidates must be finite, positive and strictly ascending; "
                             f"found {c[i]:.6g} then {c[min(i + 1, len(c) - 1)]:.6g} at "
                             f"positions {i}, {i + 1}")
        for name, want, got in (("d_min", d_min, c[0]), ("d_max", d_max, c[-1])):
            if want is not None and not np.isclose(float(want), got, rtol=1e-5):
                raise ValueError(f"the list runs from {c[0]:.6g} to {c[-1]:.6g} m, but {name} = "
                                 f"{float(want):.6g}: the parametrisation keeps both ends fixed")
        if d_min is not None and d_max is not None:
            check_range(d_min, d_max)
    steps = 1.0 / cand[:-1] - 1.0 / cand[1:]
    logits = jnp.log(steps)
    return logits - jnp.mean(logits)
