"""Constraints of a layout: footprint, minimum separation, occluder clearance, tilt, height.

Every constraint is written as violations ``g_k(layout) >= 0`` (metres, or radians for the tilt)
that are 0 exactly when the constraint holds. The smooth penalty is ``sum_k g_k^2``: zero for a
feasible layout, positive otherwise, with a gradient that pushes back towards the feasible set.
The footprint and height bounds also have an exact Euclidean projection, applied after every
optimiser step. The number of cameras is fixed by the shape of the parameters.

Everything is traceable (jit, vmap, grad in the layout; the spec is static) except
:func:`constraint_report`, a plain-Python summary for reports.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from gijax.design.objective import free_layout
from gijax.design.spec import DesignSpec, Layout
from gijax.geometry.rotations import axis_angle_to_matrix
from gijax.numerics import safe_norm

Array = jax.Array

def violations(layout: Layout, spec: DesignSpec, slack: float = 0.0) -> dict:
    """Per-constraint violations (each >= 0; 0 = satisfied), tightened by ``slack``.

    Keys and shapes: ``footprint`` (N,) m outside the footprint; ``separation`` (N, N) m short
    of ``min_separation`` (upper triangle; the diagonal and lower triangle are 0);
    ``occluder`` (N,) m inside the cylinder's radius plus ``occluder_clearance``; ``tilt`` (N,)
    radians beyond ``max_tilt_deg`` (0 when orientations are fixed); ``height`` (N,) m outside
    ``height_range`` (0 when heights are fixed). ``slack`` (not applied to the footprint,
    which the optimiser holds by projection) raises the separation, clearance and height
    margins by that many metres and tightens the tilt bound by ``100 * slack`` degrees (0.5
    degrees for 5 mm).
    """
    lay = free_layout(layout, spec)
    xy = lay.positions
    n = xy.shape[0]
    # The footprint is enforced by projection, exactly; it takes no slack.
    half = spec.half_size
    if spec.shape == "square":
        out = jnp.maximum(jnp.abs(xy) - half, 0.0)
        footprint = safe_norm(out) * (jnp.max(out, axis=-1) > 0)
    else:
        footprint = jnp.maximum(safe_norm(xy) - half, 0.0)
    diff = xy[:, None, :] - xy[None, :, :]
    dist = safe_norm(diff)
    upper = jnp.triu(jnp.ones((n, n), bool), k=1)
    separation = jnp.where(upper, jnp.maximum(spec.min_separation + slack - dist, 0.0), 0.0)
    reach = spec.occluder_radius + spec.occluder_clearance + slack
    occluder = jnp.maximum(reach - safe_norm(xy), 0.0)
    if spec.orientations:
        axis_z = axis_angle_to_matrix(lay.rotvecs)[:, 2, 2]  # cos(tilt)
        limit = math.cos(math.radians(max(spec.max_tilt_deg - 100.0 * slack, 0.0)))
        # Measured on cos(tilt): smooth where the angle itself is not (at tilt 0).
        tilt = jnp.maximum(limit - axis_z, 0.0)
    else:
        tilt = jnp.zeros(n, xy.dtype)
    if spec.heights:
        lo, hi = spec.height_range
        height = jnp.maximum(lo + slack - lay.heights, 0.0) + jnp.maximum(lay.heights - hi + slack,
                                                                         0.0)
    else:
        height = jnp.zeros(n, xy.dtype)
    return {"footprint": footprint, "separation": separation, "occluder": occluder,
            "tilt": tilt, "height": height}


def penalty(layout: Layout, spec: DesignSpec, slack: float = 0.0) -> Array:
    """Sum of squared violations (m^2; the tilt term in cos units): 0 iff feasible."""
    return sum(jnp.sum(v * v) for v in violations(layout, spec, slack).values())


def project(layout: Layout, spec: DesignSpec) -> Layout:
    """Euclidean projection of the positions onto the footprint and of the heights onto their
    range (the other constraints are left to the penalty). Works on batched layouts too."""
    xy = layout.positions
    half = spec.half_size
    if spec.shape == "square":
        xy = jnp.clip(xy, -half, half)
    else:
        r = safe_norm(xy)[..., None]
        xy = jnp.where(r > half, xy * (half / r), xy)
    h = layout.heights
    if spec.heights:
        h = jnp.clip(h, *spec.height_range)
    return layout.replace(positions=xy, heights=h)


def is_feasible(layout: Layout, spec: DesignSpec, tol: float = 1e-9) -> Array:
    """True (a bool array) when every violation is at most ``tol``."""
    return jnp.all(jnp.stack([jnp.all(v <= tol) for v in violations(layout, spec).values()]))


def constraint_report(layout: Layout, spec: DesignSpec) -> dict:
    """Plain-Python summary: worst violation per constraint, smallest separation, smallest
    clearance from the occluder axis (metres), largest tilt (degrees), feasible flag (floats
    and a bool from concrete values, not traced)."""
    lay = free_layout(layout, spec)
    xy = np.asarray(lay.positions, np.float64)
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    d[np.eye(len(xy), dtype=bool)] = np.inf
    tilt = np.degrees(np.arccos(np.clip(np.asarray(axis_angle_to_matrix(lay.rotvecs))[:, 2, 2],
                                        -1, 1)))
    rep = {k: float(np.max(np.asarray(v), initial=0.0))
           for k, v in violations(layout, spec).items()}
    rep.update(min_separation=float(d.min()), min_occluder_distance=float(
        np.linalg.norm(xy, axis=-1).min()), max_tilt_deg=float(tilt.max()),
        feasible=bool(is_feasible(layout, spec)))
    return rep
