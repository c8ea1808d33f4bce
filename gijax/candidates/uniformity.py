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
import numpy as np

from gijax.candidates.closed_form import closed_form_steps
from gijax.candidates.rig_aware import (DEFAULT_PANO, _check_options, _check_rays,
                                        _no_coverage_error, as_float_rig, parallax_angles,
                                        rig_terms)
from gijax.candidates.validation import is_concrete


def _check_candidates(candidates) -> None:
    if not is_concrete(candidates):
        return
    c = np.asarray(candidates, np.float64)
    if c.ndim != 1 or c.size < 2:
        raise ValueError(f"candidates must be a 1-D list of >= 2 distances; found shape {c.shape}")
    if not np.all(np.isfinite(c)) or c[0] <= 0.0:
        raise ValueError(f"candidates must be finite distances > 0 m; found {c.tolist()}")
    if np.any(np.diff(c) <= 0.0):
        raise ValueError(f"candidates must be strictly ascending; found {c.tolist()}")


def summarize_steps(steps) -> dict:
    """Statistics of per-step displacements (n-1,): mean, min_max_ratio, cv (std / mean), steps."""
    steps = jnp.asarray(steps)
    mean = jnp.mean(steps)
    return {
        "steps": steps,
        "mean": mean,
        "min_max_ratio": jnp.min(steps) / jnp.max(steps),
        "cv": jnp.std(steps) / mean,
    }


def closed_form_uniformity(candidates, baseline) -> dict:
    """Statistics of the parallax-angle steps (radians) for one perpendicular baseline (metres)."""
    _check_candidates(candidates)
    out = summarize_steps(closed_form_steps(jnp.asarray(candidates), baseline))
    out["unit"] = "rad"
    return out


def step_uniformity(rig, candidates, *, pano=DEFAULT_PANO, measure: str = "pixels",
                    samples: int = 4, rays=None) -> dict:
    """Per-step displacement statistics of ``candidates`` (n,) metres ascending on ``rig``.

    Returns a dict of arrays: ``steps`` (n-1,) mean displacement of each step over ray/camera
    pairs (pixels for ``measure='pixels'``, radians for 'angle'), ``mean``, ``min_max_ratio``,
    ``cv`` (std / mean of the steps), ``ray_cv`` (the coefficient of variation of the steps of
    each ray/camera pair, averaged with the pairs' weights: how uniform the list is for an
    individual ray rather than on average), ``pair_steps`` (K, n-1) the steps of every
    ray/camera pair (K = cameras x rays, camera-major), ``pair_weight`` (K,) their normalised
    weights (0 for pairs that do not count), ``pair_scale`` (K,) pixels per radian, and
    ``unit``. Visibility is evaluated over the list's own range ``[candidates[0],
    candidates[-1]]``. ``pano``, ``measure``, ``samples`` and ``rays`` as in
    :func:`gijax.candidates.rig_aware.rig_gi_candidates`.
    """
    _check_candidates(candidates)
    _check_options(pano, measure, samples)
    _check_rays(rays)
    rig = as_float_rig(rig)
    d = jnp.asarray(candidates, rig.translations.dtype)
    out, coverage = _uniformity_jit(rig, d, rays, pano=pano, measure=measure, samples=samples)
    if is_concrete(coverage) and not float(coverage) > 0.0:
        raise _no_coverage_error(rig, d[0], d[-1])
    out["unit"] = "px" if measure == "pixels" else "rad"
    return out


@functools.partial(jax.jit, static_argnames=("pano", "measure", "samples"))
def _uniformity_jit(rig, d, rays, *, pano, measure, samples):
    terms = rig_terms(rig, d[0], d[-1], pano, measure, samples, rays)
    coverage = terms.coverage
    ang = parallax_angles(terms, 1.0 / d)  # (n, K)
    per_pair = (ang[:-1] - ang[1:]).T * terms.scale[:, None]  # (K, n-1)
    w = terms.weight / jnp.where(coverage > 0.0, coverage, 1.0)
    out = summarize_steps(w @ per_pair)
    pair_mean = jnp.mean(per_pair, axis=1)
    safe = jnp.where(pair_mean > 0.0, pair_mean, 1.0)
    pair_cv = jnp.where(pair_mean > 0.0, jnp.std(per_pair, axis=1) / safe, 0.0)
    out["ray_cv"] = w @ pair_cv
    out["pair_steps"] = per_pair
    out["pair_weight"] = w
    out["pair_scale"] = terms.scale
    return out, coverage
