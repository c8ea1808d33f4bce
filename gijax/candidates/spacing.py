"""Closed-form GI candidates scaled to a rig's camera spacing.

The released G16/G8 lists are the closed form with ``b = 0.3095 m``, the side of the training
triangle: the distance from each camera to its nearest neighbour. Recomputing the list for a
new rig the way the release parametrises it means putting that rig's spacing in the same
formula. :func:`camera_spacing` is that spacing (the mean over cameras of the distance to the
nearest other camera centre), so on the training rig :func:`spacing_gi_candidates` is the
released list (to the float32 precision of the rig's translations, about 1e-8 relative), and
on a rig twice as wide it is the closed form for a baseline twice as long.

This is a different rule from the rig-aware list (:func:`rig_gi_candidates`), which equalises
the mean pixel displacement over the panorama's rays and cameras for the rig's reference
point: the two agree for a two-camera rig seen perpendicular to its baseline from a camera,
and differ where the reference point and the ray directions matter (see docs/candidates.md).

Both functions are pure JAX and differentiable with respect to the camera translations
(the nearest neighbour is piecewise constant, as any ``min``).
"""

from __future__ import annotations

import jax.numpy as jnp

from gijax.candidates.closed_form import gi_candidates
from gijax.candidates.validation import require
from gijax.numerics import sqrt_or_zero


def camera_spacing(translations):
    """Mean nearest-neighbour distance (m) between camera centres; ``translations`` (N, 3), N >= 2.

    Accepts a :class:`gijax.geometry.rig.Rig` too (its camera-to-rig translations).
    Traceable. A camera that shares its centre with another has nearest distance 0 and a zero
    gradient there (the distance is not differentiable at 0). When every camera shares its
    centre the spacing is 0: a ValueError on concrete input, a checkify debug check under a
    trace (where the closed form then gives NaN).
    """
    t = getattr(translations, "translations", translations)
    t = jnp.asarray(t)
    if t.ndim != 2 or t.shape[-1] != 3:
        raise ValueError(f"camera translations must have shape (N, 3); found {t.shape}")
    if t.shape[0] < 2:
        raise ValueError(f"a camera spacing needs at least 2 cameras; found {t.shape[0]}")
    diff = t[:, None, :] - t[None, :, :]
    d2 = jnp.sum(diff * diff, axis=-1)
    # The self-distance (0) must not be the nearest neighbour.
    d2 = jnp.where(jnp.eye(t.shape[0], dtype=bool), jnp.inf, d2)
    m2 = jnp.min(d2, axis=1)
    # sqrt'(0) is infinite: coincident centres get distance 0 through a guarded sqrt.
    nearest = sqrt_or_zero(m2)
    spacing = jnp.mean(nearest)
    require(spacing > 0.0, "cameras must not share a centre: nearest-neighbour distances "
            "{nearest} m", inputs=t, nearest=nearest)
    return spacing


def spacing_gi_candidates(rig, n: int, d_min=0.5, d_max=100.0):
    """Closed-form GI list (m, ascending, (n,)) with ``b = camera_spacing(rig)``."""
    return gi_candidates(n, d_min, d_max, camera_spacing(rig))
