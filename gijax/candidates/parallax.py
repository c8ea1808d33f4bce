r"""Parallax of a swept panorama ray as seen by one camera: the terms every GI list is built from.

One derivation, used by the rig-aware candidate solver (:mod:`gijax.candidates.rig_aware`,
with hard visibility from the rig's projection and masks) and by the rig designer
(:mod:`gijax.design.objective`, with soft visibility).

For the reference point ``o``, a unit ray ``r`` and a camera centre ``t``, the swept point
``o + d r`` is seen from the camera along ``a + d r`` with ``a = o - t``. With ``p = a . r``
and ``q = |a x r|`` the camera's parallax angle is ``phi(d) = atan2(q, d + p)``; see the
rig-aware module for why its differences are exact feature displacements. As ``d`` falls
the viewing direction turns towards ``a``; the unit tangent of that turn at the far end is
``e = (a - p r) / q``, and the camera's pixels per radian along it, ``|J_pi(R^T r) R^T e|``,
turn angles into pixels.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from gijax.geometry import cameras as cam_lib
from gijax.geometry.panorama import Panorama, lonlat_grid, ray_grid
from gijax.numerics import safe_div, safe_norm, safe_sqrt

Array = jax.Array


def rays_and_solid_angles(pano: Panorama, dtype) -> tuple[Array, Array]:
    """Unit rays (R, 3) of the panorama's pixel centres and their solid angles (R,), sr."""
    rays = ray_grid(pano, dtype).reshape(-1, 3)
    _, lat = lonlat_grid(pano, dtype)
    dlat = (pano.lat_max - pano.lat_min) / pano.height
    solid = (jnp.cos(lat) * dlat * (2.0 * math.pi / pano.width)).reshape(-1)
    return rays, solid


def sample_distances(d_min, d_max, samples: int, dtype) -> Array:
    """``samples`` distances spread geometrically over ``[d_min, d_max]`` (both ends included),
    where visibility is tested."""
    frac = jnp.linspace(0.0, 1.0, samples, dtype=dtype)
    return jnp.exp(jnp.log(d_min) + frac * (jnp.log(d_max) - jnp.log(d_min)))


def parallax_offsets(reference: Array, centres: Array, rays: Array) -> tuple[Array, Array, Array]:
    """``a = o - t_c`` (C, 3) and the ray terms ``p = a . r`` (C, R), ``q = |a x r|`` (C, R), m."""
    a = reference[None, :] - centres
    p = a @ rays.T
    q = safe_norm(jnp.cross(a[:, None, :], rays[None, :, :]))
    return a, p, q


def closest_approach(p: Array, q: Array, d_min, d_max) -> Array:
    """Smallest distance (m) between the camera centre and the swept segment ``d in [d_min,
    d_max]``: ``sqrt(q^2 + (p + d*)^2)`` at ``d* = clip(-p, d_min, d_max)``."""
    d_star = jnp.clip(-p, d_min, d_max)
    return safe_sqrt(q * q + (p + d_star) ** 2)


def motion_directions(a: Array, p: Array, q: Array, rays: Array) -> Array:
    """Unit direction ``e = (a - p r) / q`` (C, R, 3) in which a camera's view of the swept
    point turns as ``d`` falls; 0 where ``q = 0`` (no parallax, no motion)."""
    return safe_div(a[:, None, :] - p[..., None] * rays[None], q[..., None])


def pixels_per_radian(cam, rotation: Array, rays: Array, directions: Array) -> Array:
    """The camera's pixels per radian (R,) at rig-frame directions ``rays`` (R, 3) along unit
    rig-frame ``directions`` (R, 3): ``|J_pi(R^T r) R^T e|`` by a forward-mode product."""
    v_cam = rays @ rotation  # R^T r for every ray
    e_cam = directions @ rotation
    _, tangent = jax.jvp(lambda x: cam_lib.project(cam, x)[0], (v_cam,), (e_cam,))
    return safe_norm(tangent)


def parallax_angle(along: Array, perp: Array, inv_d: Array) -> Array:
    """``phi = atan2(q u, 1 + p u)`` at inverse distance ``u`` (broadcasting): the parallax
    angle ``atan2(q, d + p)`` written in ``u = 1/d`` so that ``u = 0`` (infinity) is finite."""
    return jnp.arctan2(perp * inv_d, 1.0 + along * inv_d)
