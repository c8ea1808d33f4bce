"""Step-uniformity statistics of a candidate list: the feature displacement per step.

For a rig, the displacement of step i is ``Phi(d_i) - Phi(d_{i+1})`` with ``Phi`` the cumulative
displacement of :mod:`gijax.candidates.rig_aware` (mean over panorama rays and the cameras that
see them, pixels or radians). For one perpendicular baseline (the paper's figure) it is the
parallax-angle step ``atan(b/d_i) - atan(b/d_{i+1})``. A perfectly uniform list has
``min_max_ratio = 1`` and ``cv = 0``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from gijax.candidates.rig_aware import (DEFAULT_PANO, _check_options, _check_rays, as_float_rig,
                                        parallax_angles, require_coverage, rig_terms)
from gijax.candidates.validation import guard_candidates
from gijax.numerics import safe_denominator, safe_div, sqrt_or_zero


def _std(x, axis=None):
    # jnp.std has a NaN gradient where every value is equal (sqrt'(0)): a list's zero steps on a
    # rig without coverage, or the steps of a camera without parallax.
    return sqrt_or_zero(jnp.var(x, axis=axis))


def summarize_steps(steps) -> dict:
    """Statistics of per-step displacements (n-1,): mean, min_max_ratio, cv (std / mean), steps."""
    steps = jnp.asarray(steps)
    mean = jnp.mean(steps)
    return {
        "steps": steps,
        "mean": mean,
        "min_max_ratio": safe_div(jnp.min(steps), jnp.max(steps)),
        "cv": safe_div(_std(steps), mean),
    }


def step_uniformity(rig, candidates, *, pano=DEFAULT_PANO, measure: str = "pixels",
                    samples: int = 4, rays=None) -> dict:
    """Per-step displacement statistics of ``candidates`` (n,) metres ascending on ``rig``.

    Returns a dict of arrays: ``steps`` (n-1,) mean displacement of each step over ray/camera
    pairs (pixels for ``measure='pixels'``, radians for 'angle'; the unit's name is
    ``MEASURE_UNITS[measure]``), ``mean``, ``min_max_ratio``, ``cv`` (std / mean of the steps),
    ``ray_cv`` (the coefficient of variation of the steps of each ray/camera pair, averaged with
    the pairs' weights: how uniform the list is for an individual ray rather than on average),
    ``pair_steps`` (K, n-1) the steps of every ray/camera pair (K = cameras x rays,
    camera-major), ``pair_weight`` (K,) their normalised weights (0 for pairs that do not
    count) and ``pair_scale`` (K,) pixels per radian. Visibility is evaluated over the list's
    own range ``[candidates[0], candidates[-1]]``. ``pano``, ``measure``, ``samples`` and
    ``rays`` as in :func:`gijax.candidates.rig_aware.rig_gi_candidates`.

    Traceable (jit, vmap, grad in the rig and the candidates). On concrete input a bad list or
    a rig without coverage raises ValueError; under a trace those are checkify debug checks and
    a rig without coverage gives zero steps and ratios.
    """
    guard_candidates(candidates)
    _check_options(pano, measure, samples)
    _check_rays(rays)
    rig = as_float_rig(rig)
    d = jnp.asarray(candidates, rig.translations.dtype)
    out, coverage = _uniformity_jit(rig, d, rays, pano=pano, measure=measure, samples=samples)
    require_coverage(coverage, rig, d[0], d[-1])
    return out


@functools.partial(jax.jit, static_argnames=("pano", "measure", "samples"))
def _uniformity_jit(rig, d, rays, *, pano, measure, samples):
    # One compiled program per (pano, measure, samples) for eager callers.
    terms = rig_terms(rig, d[0], d[-1], pano, measure, samples, rays)
    coverage = terms.coverage
    ang = parallax_angles(terms, 1.0 / d)  # (n, K)
    per_pair = (ang[:-1] - ang[1:]).T * terms.scale[:, None]  # (K, n-1)
    w = terms.weight / safe_denominator(coverage)
    out = summarize_steps(w @ per_pair)
    pair_mean = jnp.mean(per_pair, axis=1)
    pair_cv = jnp.where(pair_mean > 0.0, safe_div(_std(per_pair, axis=1), pair_mean), 0.0)
    out["ray_cv"] = w @ pair_cv
    out["pair_steps"] = per_pair
    out["pair_weight"] = w
    out["pair_scale"] = terms.scale
    return out, coverage
