"""Procedural scenes as fixed-size pytrees of primitives, so one jit compile serves every seed.

A :class:`Scene` is expressed in the **rig frame** (metres): +z is the rig's viewing axis, which
points up in the world, so the ground is the plane ``z = reference_z - height``. Random scenes
place every object at a random azimuth around the rig, which is the same as a random rig yaw.

Primitive kinds and their fixed maximum counts (unused slots have ``active = False``):

* ``NUM_PLANES`` horizontal planes (ground, ceiling), limited to a horizontal range
  ``plane_extent`` from the ray origin (a far horizon).
* one room: an axis-aligned box rotated about +z, seen from inside (walls, floor, ceiling).
* ``NUM_BOXES`` solid boxes rotated about +z (buildings, furniture, beams, slabs).
* ``NUM_SPHERES`` spheres (tree canopies, lamps, balls).
* ``NUM_CYLINDERS`` vertical capped cylinders (trunks, columns, thin poles).
* ``NUM_CAPSULES`` capsules around a segment (wires, pipes, cords, branches).

Every primitive has a material (row ``OFFSET_<KIND> + k`` of the ``mat_*`` arrays): a three-colour
palette, a solid-noise frequency and a stripe/check pattern evaluated at the 3D hit point, so the
texture of a surface point is the same from every viewpoint.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

Array = jax.Array

FAR = 1e6
NUM_PLANES = 2
NUM_BOXES = 24
NUM_SPHERES = 12
NUM_CYLINDERS = 16
NUM_CAPSULES = 16
OFFSET_PLANES = 0
OFFSET_ROOM = OFFSET_PLANES + NUM_PLANES
OFFSET_BOXES = OFFSET_ROOM + 1
OFFSET_SPHERES = OFFSET_BOXES + NUM_BOXES
OFFSET_CYLINDERS = OFFSET_SPHERES + NUM_SPHERES
OFFSET_CAPSULES = OFFSET_CYLINDERS + NUM_CYLINDERS
NUM_PRIMITIVES = OFFSET_CAPSULES + NUM_CAPSULES
SKY_ID = -1
STYLES = ("indoor", "outdoor")
# Horizontal range of the ground plane: rays grazing the ground further out see the sky.
PLANE_EXTENT = 5000.0
# Pattern kinds of a material.
PATTERN_NONE, PATTERN_STRIPES, PATTERN_CHECKS = 0, 1, 2


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Scene:
    """Primitives, materials, light and sky of one scene (all leaves; shapes fixed, see module)."""

    plane_height: Array  # (NUM_PLANES,) z of each horizontal plane, rig frame
    plane_active: Array  # (NUM_PLANES,) bool
    plane_extent: Array  # () horizontal range of the planes, metres
    room_centre: Array  # (3,)
    room_half: Array  # (3,) half extents
    room_yaw: Array  # () rotation about +z, radians
    room_active: Array  # () bool
    box_centre: Array  # (NUM_BOXES, 3)
    box_half: Array  # (NUM_BOXES, 3)
    box_yaw: Array  # (NUM_BOXES,)
    box_active: Array  # (NUM_BOXES,)
    sphere_centre: Array  # (NUM_SPHERES, 3)
    sphere_radius: Array  # (NUM_SPHERES,)
    sphere_active: Array
    cylinder_xy: Array  # (NUM_CYLINDERS, 2) axis position
    cylinder_radius: Array  # (NUM_CYLINDERS,)
    cylinder_z0: Array  # (NUM_CYLINDERS,) bottom
    cylinder_z1: Array  # (NUM_CYLINDERS,) top
    cylinder_active: Array
    capsule_a: Array  # (NUM_CAPSULES, 3) segment start
    capsule_b: Array  # (NUM_CAPSULES, 3) segment end
    capsule_radius: Array  # (NUM_CAPSULES,)
    capsule_active: Array
    mat_colours: Array  # (NUM_PRIMITIVES, 3, 3) palette, RGB in [0, 1]
    mat_noise_freq: Array  # (NUM_PRIMITIVES,) base noise frequency, cycles per metre
    mat_pattern: Array  # (NUM_PRIMITIVES,) int32 PATTERN_*
    mat_pattern_freq: Array  # (NUM_PRIMITIVES,) cycles per metre
    mat_pattern_axis: Array  # (NUM_PRIMITIVES, 3) unit stripe normal
    mat_pattern_strength: Array  # (NUM_PRIMITIVES,) in [0, 1]
    mat_offset: Array  # (NUM_PRIMITIVES, 3) noise-space offset (decorrelates primitives)
    light_dir: Array  # (3,) unit vector towards the light
    light_strength: Array  # ()
    ambient: Array  # ()
    sky_zenith: Array  # (3,) RGB
    sky_horizon: Array  # (3,) RGB
    cloud_freq: Array  # () cycles per radian
    cloud_cover: Array  # () in [0, 1]

    def replace(self, **kw) -> "Scene":
        return dataclasses.replace(self, **kw)


@dataclasses.dataclass(frozen=True)
class Clearance:
    """The rig's keep-out zone relative to its reference point, metres.

    No primitive comes within ``margin`` of the cylinder of radius ``radius`` spanning
    ``z_lo..z_hi`` that holds every camera centre and the rig's body (plain floats).
    """

    radius: float
    z_lo: float
    z_hi: float
    margin: float = 0.5


def rig_clearance(rig, margin: float = 0.5) -> Clearance:
    """The keep-out cylinder of a :class:`gijax.geometry.rig.Rig` around its reference point."""
    ref = np.asarray(rig.reference, np.float64)
    t = np.asarray(rig.translations, np.float64) - ref
    radius = float(np.max(np.hypot(t[:, 0], t[:, 1])))
    z_lo, z_hi = float(t[:, 2].min()), float(t[:, 2].max())
    occ = rig.occluder
    if occ is not None:
        ox, oy = float(occ.x) - ref[0], float(occ.y) - ref[1]
        radius = max(radius, math.hypot(ox, oy) + float(occ.radius))
        z_lo = min(z_lo, float(occ.z_min) - ref[2])
        z_hi = max(z_hi, float(occ.z_max) - ref[2])
    return Clearance(radius, z_lo, z_hi, margin)


def _f(x) -> Array:
    return jnp.asarray(x, jnp.float32)


def empty_scene() -> Scene:
    """A scene with nothing in it (every ray sees the sky); base for hand-built test scenes."""
    z3 = jnp.zeros(3, jnp.float32)
    p = NUM_PRIMITIVES
    grey = jnp.tile(jnp.array([[0.5, 0.5, 0.5], [0.3, 0.3, 0.3], [0.8, 0.8, 0.8]],
                              jnp.float32), (p, 1, 1))
    return Scene(
        plane_height=jnp.zeros(NUM_PLANES, jnp.float32),
        plane_active=jnp.zeros(NUM_PLANES, bool), plane_extent=_f(PLANE_EXTENT),
        room_centre=z3, room_half=jnp.ones(3, jnp.float32), room_yaw=_f(0.0),
        room_active=jnp.asarray(False),
        box_centre=jnp.zeros((NUM_BOXES, 3), jnp.float32),
        box_half=jnp.ones((NUM_BOXES, 3), jnp.float32), box_yaw=jnp.zeros(NUM_BOXES, jnp.float32),
        box_active=jnp.zeros(NUM_BOXES, bool),
        sphere_centre=jnp.zeros((NUM_SPHERES, 3), jnp.float32),
        sphere_radius=jnp.ones(NUM_SPHERES, jnp.float32),
        sphere_active=jnp.zeros(NUM_SPHERES, bool),
        cylinder_xy=jnp.zeros((NUM_CYLINDERS, 2), jnp.float32),
        cylinder_radius=jnp.ones(NUM_CYLINDERS, jnp.float32),
        cylinder_z0=jnp.zeros(NUM_CYLINDERS, jnp.float32),
        cylinder_z1=jnp.ones(NUM_CYLINDERS, jnp.float32),
        cylinder_active=jnp.zeros(NUM_CYLINDERS, bool),
        capsule_a=jnp.zeros((NUM_CAPSULES, 3), jnp.float32),
        capsule_b=jnp.ones((NUM_CAPSULES, 3), jnp.float32),
        capsule_radius=jnp.ones(NUM_CAPSULES, jnp.float32),
        capsule_active=jnp.zeros(NUM_CAPSULES, bool),
        mat_colours=grey, mat_noise_freq=jnp.ones(p, jnp.float32),
        mat_pattern=jnp.zeros(p, jnp.int32), mat_pattern_freq=jnp.ones(p, jnp.float32),
        mat_pattern_axis=jnp.tile(jnp.array([0.0, 0.0, 1.0], jnp.float32), (p, 1)),
        mat_pattern_strength=jnp.zeros(p, jnp.float32), mat_offset=jnp.zeros((p, 3), jnp.float32),
        light_dir=jnp.array([0.3, 0.2, 0.93], jnp.float32) / jnp.linalg.norm(
            jnp.array([0.3, 0.2, 0.93])),
        light_strength=_f(0.6), ambient=_f(0.5),
        sky_zenith=jnp.array([0.35, 0.55, 0.9], jnp.float32),
        sky_horizon=jnp.array([0.8, 0.85, 0.92], jnp.float32), cloud_freq=_f(3.0),
        cloud_cover=_f(0.4),
    )


def sphere_scene(centre, radius, key: Array | None = None) -> Scene:
    """Only one sphere (slot 0) of ``radius`` metres around ``centre`` (3,), randomly textured."""
    scene = empty_scene()
    scene = scene.replace(
        sphere_centre=scene.sphere_centre.at[0].set(jnp.asarray(centre, jnp.float32)),
        sphere_radius=scene.sphere_radius.at[0].set(_f(radius)),
        sphere_active=scene.sphere_active.at[0].set(True))
    if key is None:
        return scene
    dist = jnp.full((NUM_PRIMITIVES,), _f(radius))
    spec = jnp.tile(jnp.array([0.0, 1.0, 0.1, 0.8, 0.25, 0.9], jnp.float32), (NUM_PRIMITIVES, 1))
    return _with_materials(scene, key, dist, spec)


def plane_scene(height, extent: float = PLANE_EXTENT) -> Scene:
    """Only a horizontal plane at z = ``height`` (rig frame), e.g. the ground below the rig."""
    scene = empty_scene()
    return scene.replace(plane_height=scene.plane_height.at[0].set(_f(height)),
                         plane_active=scene.plane_active.at[0].set(True),
                         plane_extent=_f(extent))


# ----------------------------------------------------------------------------------------------
# Random scenes


class _Rand:
    """Uniform numbers handed out in order from one pre-drawn block.

    Drawing every scene parameter from a single ``jax.random.uniform`` call keeps the jitted
    scene generator small (one counter-based generator instead of one per parameter), which
    makes it compile in a fraction of the time; the draws stay a pure function of the key.
    """

    SIZE = 4096

    def __init__(self, key: Array):
        self.pool = jax.random.uniform(key, (self.SIZE,), jnp.float32)
        self.used = 0

    def __call__(self, shape=()) -> Array:
        n = int(np.prod(shape, dtype=np.int64))
        if self.used + n > self.SIZE:
            raise ValueError(f"scene generator needs more than {self.SIZE} random numbers")
        out = self.pool[self.used:self.used + n].reshape(shape)
        self.used += n
        return out


def _u(r: _Rand, shape, lo, hi):
    return lo + (hi - lo) * r(shape)


def _logu(r: _Rand, shape, lo, hi):
    return jnp.exp(_u(r, shape, math.log(lo), math.log(hi)))


def _bernoulli(r: _Rand, p, shape=()):
    return r(shape) < p


def _randint(r: _Rand, shape, lo: int, hi: int) -> Array:
    """Integers in [lo, hi)."""
    return jnp.minimum(lo + jnp.floor(r(shape) * (hi - lo)).astype(jnp.int32), hi - 1)


def _normal(r: _Rand, shape) -> Array:
    """Standard normal numbers by the Box-Muller transform."""
    u1 = jnp.maximum(r(shape), 1e-7)
    u2 = r(shape)
    return jnp.sqrt(-2.0 * jnp.log(u1)) * jnp.cos(2.0 * jnp.pi * u2)


def _count_mask(r: _Rand, n: int, lo: int, hi: int) -> Array:
    """(n,) bool with a random number in [lo, hi] of leading slots set."""
    return jnp.arange(n) < _randint(r, (), lo, hi + 1)


def _polar(r: _Rand, shape, rho):
    ang = _u(r, shape, -math.pi, math.pi)
    return jnp.stack([rho * jnp.cos(ang), rho * jnp.sin(ang)], -1)


def _push_xy(xy: Array, min_rho: Array) -> Array:
    """Move horizontal positions (..., 2) radially out to at least ``min_rho`` from the axis."""
    rho = jnp.sqrt(jnp.sum(xy * xy, -1, keepdims=True))
    unit = jnp.where(rho > 1e-6, xy / jnp.maximum(rho, 1e-6), jnp.array([1.0, 0.0]))
    return jnp.where(rho < min_rho[..., None], unit * min_rho[..., None], xy)


def _segment_distance(a: Array, b: Array) -> Array:
    """Distance (K,) of segments a-b (K, 3) to the origin."""
    ba = b - a
    s = jnp.clip(-jnp.sum(a * ba, -1) / jnp.maximum(jnp.sum(ba * ba, -1), 1e-12), 0.0, 1.0)
    return jnp.linalg.norm(a + s[:, None] * ba, axis=-1)


def _keepout_violation(rho, reach, z_min, z_max, clear: Clearance):
    """True where an object of horizontal reach ``reach`` around a centre at horizontal
    distance ``rho`` spanning ``z_min..z_max`` enters the inflated keep-out cylinder."""
    near_xy = rho - reach < clear.radius + clear.margin
    near_z = (z_max > clear.z_lo - clear.margin) & (z_min < clear.z_hi + clear.margin)
    return near_xy & near_z


def _capsule_violation(a, b, r, clear: Clearance) -> Array:
    s = jnp.linspace(0.0, 1.0, 65)
    pts = a[:, None] + s[None, :, None] * (b - a)[:, None]
    rho = jnp.linalg.norm(pts[..., :2], axis=-1)
    bad = _keepout_violation(rho, r[:, None], pts[..., 2] - r[:, None],
                             pts[..., 2] + r[:, None], clear)
    return jnp.any(bad, -1)


def _hsv_to_rgb(h, s, v):
    """Vectorised HSV (all in [0, 1]) to RGB (..., 3)."""
    k = jnp.stack([5.0, 3.0, 1.0])
    kk = jnp.mod(k + h[..., None] * 6.0, 6.0)
    return v[..., None] - v[..., None] * s[..., None] * jnp.clip(jnp.minimum(kk, 4.0 - kk), 0, 1)


def _with_materials(scene: Scene, key: Array, dist: Array, spec: Array) -> Scene:
    """Random materials for every primitive.

    ``dist`` (P,) is each primitive's distance from the reference point (metres) and sets the
    base noise frequency so that texture detail starts at a few pixels wide on screen near and
    far; ``spec`` (P, 6) gives hue range, saturation range and value range of its palette.
    """
    p = NUM_PRIMITIVES
    r = _Rand(key)
    hue = _u(r, (p,), 0.0, 1.0) * (spec[:, 1] - spec[:, 0]) + spec[:, 0]
    sat = _u(r, (p,), 0.0, 1.0) * (spec[:, 3] - spec[:, 2]) + spec[:, 2]
    val = _u(r, (p,), 0.0, 1.0) * (spec[:, 5] - spec[:, 4]) + spec[:, 4]
    c0 = _hsv_to_rgb(jnp.mod(hue, 1.0), sat, val)
    hue1 = jnp.mod(hue + _u(r, (p,), -0.08, 0.08), 1.0)
    val1 = jnp.clip(val * _u(r, (p,), 0.35, 0.75), 0.03, 1.0)
    c1 = _hsv_to_rgb(hue1, jnp.clip(sat * 1.2, 0, 1), val1)
    hue2 = jnp.mod(hue + _u(r, (p,), -0.5, 0.5), 1.0)
    c2 = _hsv_to_rgb(hue2, _u(r, (p,), 0.05, 0.8), _u(r, (p,), 0.15, 0.95))
    colours = jnp.stack([c0, c1, c2], 1)
    freq = _logu(r, (p,), 3.0, 10.0) / jnp.maximum(dist, 0.5)
    pick = r((p,))
    pattern = (pick > 0.3).astype(jnp.int32) + (pick > 0.65).astype(jnp.int32)
    pattern_freq = freq * _logu(r, (p,), 0.7, 4.0)
    axis = _normal(r, (p, 3))
    # Half the stripes run horizontally (like courses of bricks or floors of a building).
    horizontal = _bernoulli(r, 0.5, (p,))
    axis = jnp.where(horizontal[:, None], jnp.array([0.0, 0.0, 1.0]), axis)
    axis = axis / jnp.linalg.norm(axis, axis=-1, keepdims=True)
    strength = _u(r, (p,), 0.35, 0.9)
    offset = _u(r, (p, 3), -1000.0, 1000.0)
    return scene.replace(mat_colours=colours, mat_noise_freq=freq,
                         mat_pattern=pattern.astype(jnp.int32), mat_pattern_freq=pattern_freq,
                         mat_pattern_axis=axis, mat_pattern_strength=strength, mat_offset=offset)


def _spec(n: int, hue, sat, val) -> Array:
    return jnp.tile(jnp.array([*hue, *sat, *val], jnp.float32), (n, 1))


def _lighting(r: _Rand, indoor: bool) -> dict:
    az = _u(r, (), -math.pi, math.pi)
    # The cameras look up, so light from below the horizon (bounce light, lamps) keeps the
    # downward-facing surfaces they see from being flat.
    el = _u(r, (), -0.6, 1.3) if indoor else _u(r, (), 0.2, 1.4)
    light = jnp.stack([jnp.cos(el) * jnp.cos(az), jnp.cos(el) * jnp.sin(az), jnp.sin(el)])
    zen = _hsv_to_rgb(_u(r, (), 0.53, 0.64), _u(r, (), 0.3, 0.75), _u(r, (), 0.6, 0.95))
    hor = _hsv_to_rgb(_u(r, (), 0.05, 0.6), _u(r, (), 0.0, 0.2), _u(r, (), 0.8, 1.0))
    return dict(light_dir=light, light_strength=_u(r, (), 0.35, 0.7),
                ambient=_u(r, (), 0.45, 0.7), sky_zenith=zen, sky_horizon=hor,
                cloud_freq=_logu(r, (), 2.0, 6.0), cloud_cover=_u(r, (), 0.1, 0.9))


def _outdoor(key: Array, clear: Clearance) -> tuple[Scene, Array, Array]:
    r = _Rand(key)
    keep = clear.radius + clear.margin
    z_top = clear.z_hi + clear.margin
    height = _u(r, (), max(1.0, -clear.z_lo + clear.margin + 0.1), 2.2)
    ground = -height
    ceil = jnp.asarray(False)

    # Boxes: buildings, overhead slabs, small near boxes, far blocks beyond 100 m.
    nb = (12, 5, 4, 3)
    bh_xy = _u(r, (nb[0], 2), 2.0, 14.0)
    # Street canyons: near buildings are tall enough to fill the upward view.
    b_rho = _logu(r, (nb[0],), 4.0, 80.0)
    b_rho = jnp.maximum(b_rho, keep + jnp.linalg.norm(bh_xy, axis=-1) + 0.3)
    b_xy = _polar(r, (nb[0],), b_rho)
    b_h = _logu(r, (nb[0],), 6.0, 90.0)
    buildings = (jnp.concatenate([b_xy, (ground + b_h / 2)[:, None]], -1),
                 jnp.concatenate([bh_xy, (b_h / 2)[:, None]], -1),
                 _count_mask(r, nb[0], 6, nb[0]))
    s_xy = _u(r, (nb[1], 2), -10.0, 10.0)
    s_half = jnp.stack([_u(r, (nb[1],), 0.5, 6.0), _u(r, (nb[1],), 0.3, 3.0),
                        _u(r, (nb[1],), 0.05, 0.5)], -1)
    s_z = z_top + _logu(r, (nb[1],), 0.3, 12.0) + s_half[:, 2]
    slabs = (jnp.concatenate([s_xy, s_z[:, None]], -1), s_half,
             _count_mask(r, nb[1], 0, nb[1]))
    n_half = _u(r, (nb[2], 3), 0.1, 0.8)
    n_rho = keep + jnp.linalg.norm(n_half[:, :2], axis=-1) + _logu(r, (nb[2],), 0.05, 3.0)
    n_z = _u(r, (nb[2],), -1.0, 3.0)
    near = (jnp.concatenate([_polar(r, (nb[2],), n_rho), n_z[:, None]], -1), n_half,
            _count_mask(r, nb[2], 1, nb[2]))
    f_half = jnp.stack([_u(r, (nb[3],), 20.0, 80.0), _u(r, (nb[3],), 10.0, 60.0),
                        _u(r, (nb[3],), 20.0, 120.0)], -1)
    f_rho = _u(r, (nb[3],), 150.0, 400.0)
    far = (jnp.concatenate([_polar(r, (nb[3],), f_rho), (ground + f_half[:, 2])[:, None]],
                           -1), f_half, _count_mask(r, nb[3], 0, nb[3]))
    groups = (buildings, slabs, near, far)
    box_centre = jnp.concatenate([g[0] for g in groups])
    box_half = jnp.concatenate([g[1] for g in groups])
    box_active = jnp.concatenate([g[2] for g in groups])
    box_yaw = _u(r, (NUM_BOXES,), -math.pi, math.pi)

    # Trees: trunk cylinders with sphere canopies on top; free-floating and near spheres.
    nt = 6
    canopy_r = _u(r, (nt,), 1.5, 6.0)
    trunk_r = _u(r, (nt,), 0.08, 0.5)
    trunk_h = _u(r, (nt,), 3.0, 12.0)
    t_rho = jnp.maximum(_logu(r, (nt,), 2.0, 40.0), keep + canopy_r + 0.2)
    t_xy = _polar(r, (nt,), t_rho)
    tree_on = _count_mask(r, nt, 0, nt)
    canopy_c = jnp.concatenate([t_xy, (ground + trunk_h + 0.6 * canopy_r)[:, None]], -1)
    fl_r = _logu(r, (4,), 0.1, 3.0)
    fl_c = jnp.concatenate([_polar(r, (4,), _logu(r, (4,), 2.0, 60.0)),
                            _u(r, (4, 1), 0.0, 25.0)], -1)
    nr_r = _u(r, (2,), 0.05, 0.4)
    nr_c = jnp.concatenate([_polar(r, (2,), keep + nr_r + _u(r, (2,), 0.0, 1.5)),
                            _u(r, (2, 1), -0.5, 2.0)], -1)
    sphere_centre = jnp.concatenate([canopy_c, fl_c, nr_c])
    sphere_radius = jnp.concatenate([canopy_r, fl_r, nr_r])
    sphere_active = jnp.concatenate([tree_on, _count_mask(r, 4, 0, 4),
                                     _count_mask(r, 2, 0, 2)])

    # Cylinders: the trunks, thin poles (one of them close), towers and chimneys far away.
    np_ = 6
    pole_r = _u(r, (np_,), 0.02, 0.15)
    pole_rho = _logu(r, (np_,), 1.0, 40.0)
    pole_rho = pole_rho.at[0].set(_u(r, (), 0.05, 1.5))
    pole_rho = pole_rho + keep + pole_r
    pole_xy = _polar(r, (np_,), pole_rho)
    pole_top = ground + _u(r, (np_,), 4.0, 12.0)
    tw_r = _u(r, (4,), 0.5, 4.0)
    tw_xy = _polar(r, (4,), _u(r, (4,), 20.0, 180.0))
    tw_top = ground + _logu(r, (4,), 10.0, 120.0)
    cylinder_xy = jnp.concatenate([t_xy, pole_xy, tw_xy])
    cylinder_radius = jnp.concatenate([trunk_r, pole_r, tw_r])
    cylinder_z0 = jnp.full((NUM_CYLINDERS,), ground - 0.1)
    cylinder_z1 = jnp.concatenate([ground + trunk_h + 0.2 * canopy_r, pole_top, tw_top])
    cylinder_active = jnp.concatenate([tree_on, _count_mask(r, np_, 1, np_),
                                       _count_mask(r, 4, 0, 4)])

    # Capsules: overhead wires (one just above the rig), guy wires from pole tops to the ground.
    nw = 10
    w_dir = _u(r, (nw,), -math.pi, math.pi)
    w_u = jnp.stack([jnp.cos(w_dir), jnp.sin(w_dir), _u(r, (nw,), -0.05, 0.05)], -1)
    w_perp = jnp.stack([-jnp.sin(w_dir), jnp.cos(w_dir), jnp.zeros(nw)], -1)
    w_off = _u(r, (nw,), -25.0, 25.0)
    w_z = z_top + _logu(r, (nw,), 0.2, 15.0)
    w_z = w_z.at[0].set(z_top + _u(r, (), 0.05, 1.0))
    w_mid = w_perp * w_off[:, None] + jnp.stack([jnp.zeros(nw), jnp.zeros(nw), w_z], -1)
    w_len = _u(r, (nw,), 30.0, 160.0)
    w_a = w_mid - w_u * w_len[:, None] / 2
    w_b = w_mid + w_u * w_len[:, None] / 2
    w_r = _logu(r, (nw,), 0.004, 0.04)
    ng = 6
    g_a = jnp.concatenate([pole_xy, pole_top[:, None]], -1)
    g_b = jnp.concatenate([pole_xy + _polar(r, (ng,), _u(r, (ng,), 2.0, 6.0)),
                           jnp.full((ng, 1), ground)], -1)
    g_r = _u(r, (ng,), 0.005, 0.02)
    capsule_a = jnp.concatenate([w_a, g_a])
    capsule_b = jnp.concatenate([w_b, g_b])
    capsule_radius = jnp.concatenate([w_r, g_r])
    capsule_active = jnp.concatenate([_count_mask(r, nw, 2, nw),
                                      cylinder_active[nt:nt + np_]
                                      & _bernoulli(r, 0.5, (ng,))])

    scene = empty_scene().replace(
        plane_height=jnp.stack([ground, z_top + 5.0]),
        plane_active=jnp.stack([jnp.asarray(True), ceil]),
        box_centre=box_centre, box_half=box_half, box_yaw=box_yaw, box_active=box_active,
        sphere_centre=sphere_centre, sphere_radius=sphere_radius, sphere_active=sphere_active,
        cylinder_xy=cylinder_xy, cylinder_radius=cylinder_radius, cylinder_z0=cylinder_z0,
        cylinder_z1=cylinder_z1, cylinder_active=cylinder_active, capsule_a=capsule_a,
        capsule_b=capsule_b, capsule_radius=capsule_radius, capsule_active=capsule_active,
        **_lighting(r, indoor=False))
    spec = jnp.concatenate([
        _spec(1, (0.05, 0.35), (0.1, 0.5), (0.25, 0.6)),  # ground
        _spec(1, (0.0, 1.0), (0.0, 0.3), (0.4, 0.9)),  # ceiling plane (unused outdoors)
        _spec(1, (0.0, 1.0), (0.0, 0.3), (0.4, 0.9)),  # room (unused outdoors)
        _spec(nb[0], (0.0, 1.0), (0.0, 0.35), (0.35, 0.95)),  # buildings
        _spec(nb[1], (0.0, 1.0), (0.0, 0.6), (0.3, 0.9)),  # slabs
        _spec(nb[2], (0.0, 1.0), (0.3, 0.9), (0.3, 0.95)),  # near boxes
        _spec(nb[3], (0.0, 1.0), (0.0, 0.25), (0.4, 0.85)),  # far blocks
        _spec(nt, (0.2, 0.4), (0.35, 0.8), (0.2, 0.65)),  # canopies
        _spec(6, (0.0, 1.0), (0.4, 0.9), (0.4, 1.0)),  # balls
        _spec(nt, (0.03, 0.12), (0.3, 0.7), (0.15, 0.45)),  # trunks
        _spec(np_, (0.0, 1.0), (0.0, 0.4), (0.2, 0.8)),  # poles
        _spec(4, (0.0, 1.0), (0.0, 0.3), (0.3, 0.85)),  # towers
        _spec(nw + ng, (0.0, 1.0), (0.0, 0.3), (0.05, 0.35)),  # wires
    ])
    return scene, spec, height


def _indoor(key: Array, clear: Clearance) -> tuple[Scene, Array, Array]:
    r = _Rand(key)
    keep = clear.radius + clear.margin
    z_top = clear.z_hi + clear.margin
    height = _u(r, (), max(0.8, -clear.z_lo + clear.margin + 0.1), 2.0)
    floor = -height
    big = _bernoulli(r, 0.3)
    half_xy = jnp.where(big, _u(r, (2,), 10.0, 35.0), _u(r, (2,), 1.5, 8.0))
    half_xy = jnp.maximum(half_xy, keep + 0.3)
    ceiling = z_top + jnp.where(big, _u(r, (), 3.0, 15.0), _u(r, (), 0.5, 3.5))
    room_yaw = _u(r, (), -math.pi, math.pi)
    offset = _u(r, (2,), -1.0, 1.0) * (half_xy - keep - 0.2)
    cy, sy = jnp.cos(room_yaw), jnp.sin(room_yaw)
    rot = jnp.array([[cy, -sy], [sy, cy]])

    def to_rig(xy_room):
        """Room-frame horizontal positions (..., 2) -> rig frame."""
        return (xy_room - offset) @ rot.T

    def inside(k, n, margin):
        return _u(k, (n, 2), -1.0, 1.0) * (half_xy - margin)

    room_centre = jnp.concatenate([to_rig(jnp.zeros(2)), ((floor + ceiling) / 2)[None]])
    room_half = jnp.concatenate([half_xy, ((ceiling - floor) / 2)[None]])

    # Boxes: furniture on the floor, beams under the ceiling, ducts/panels, shelves at walls.
    fur_half = jnp.stack([_u(r, (8,), 0.2, 1.2), _u(r, (8,), 0.2, 0.8),
                          _u(r, (8,), 0.2, 1.3)], -1)
    fur_xy = _push_xy(to_rig(inside(r, 8, 0.5)),
                      keep + jnp.linalg.norm(fur_half[:, :2], axis=-1) + 0.05)
    fur = (jnp.concatenate([fur_xy, (floor + fur_half[:, 2])[:, None]], -1), fur_half,
           _count_mask(r, 8, 2, 8))
    along_x = _bernoulli(r, 0.5)
    beam_w = _u(r, (6,), 0.08, 0.35)
    beam_d = _u(r, (6,), 0.1, 0.6)
    beam_pos = _u(r, (6,), -1.0, 1.0)
    beam_room = jnp.where(along_x, jnp.stack([jnp.zeros(6), beam_pos * half_xy[1]], -1),
                          jnp.stack([beam_pos * half_xy[0], jnp.zeros(6)], -1))
    beam_half = jnp.where(along_x, jnp.stack([jnp.full(6, half_xy[0]), beam_w, beam_d], -1),
                          jnp.stack([beam_w, jnp.full(6, half_xy[1]), beam_d], -1))
    beams = (jnp.concatenate([to_rig(beam_room), (ceiling - beam_half[:, 2])[:, None]], -1),
             beam_half, _count_mask(r, 6, 0, 6))
    duct_half = jnp.stack([_u(r, (4,), 0.3, 3.0), _u(r, (4,), 0.2, 1.0),
                           _u(r, (4,), 0.05, 0.4)], -1)
    duct_z = ceiling - _u(r, (4,), 0.0, 1.5) - duct_half[:, 2]
    ducts = (jnp.concatenate([to_rig(inside(r, 4, 0.5)), duct_z[:, None]], -1), duct_half,
             _count_mask(r, 4, 0, 4))
    sh_half = jnp.stack([_u(r, (6,), 0.4, 1.5), _u(r, (6,), 0.15, 0.4),
                         _u(r, (6,), 0.8, 2.0)], -1)
    wall = _randint(r, (6,), 0, 4)
    t = _u(r, (6,), -0.9, 0.9)
    sh_room = jnp.stack([
        jnp.where(wall < 2, t * half_xy[0], jnp.where(wall == 2, 1.0, -1.0) * (half_xy[0] - 0.4)),
        jnp.where(wall >= 2, t * half_xy[1], jnp.where(wall == 0, 1.0, -1.0) * (half_xy[1] - 0.4)),
    ], -1)
    sh_half = jnp.where((wall >= 2)[:, None], sh_half[:, jnp.array([1, 0, 2])], sh_half)
    shelves = (jnp.concatenate([to_rig(sh_room), (floor + sh_half[:, 2])[:, None]], -1), sh_half,
               _count_mask(r, 6, 0, 6))
    groups = (fur, beams, ducts, shelves)
    box_centre = jnp.concatenate([g[0] for g in groups])
    box_half = jnp.concatenate([g[1] for g in groups])
    box_active = jnp.concatenate([g[2] for g in groups])
    box_yaw = jnp.full((NUM_BOXES,), room_yaw).at[:8].add(_u(r, (8,), -0.5, 0.5))

    # Spheres: hanging lamps (with cords) and balls on the floor.
    lamp_r = _u(r, (6,), 0.08, 0.4)
    lamp_xy = _push_xy(to_rig(inside(r, 6, 0.5)), keep + lamp_r + 0.05)
    lamp_z = ceiling - _u(r, (6,), 0.3, 2.5)
    lamp_z = jnp.maximum(lamp_z, floor + lamp_r + 0.5)
    lamp_on = _count_mask(r, 6, 0, 6)
    ball_r = _u(r, (6,), 0.1, 0.6)
    ball_xy = _push_xy(to_rig(inside(r, 6, 0.6)), keep + ball_r + 0.05)
    sphere_centre = jnp.concatenate([
        jnp.concatenate([lamp_xy, lamp_z[:, None]], -1),
        jnp.concatenate([ball_xy, (floor + ball_r)[:, None]], -1)])
    sphere_radius = jnp.concatenate([lamp_r, ball_r])
    sphere_active = jnp.concatenate([lamp_on, _count_mask(r, 6, 0, 6)])

    # Cylinders: columns floor to ceiling, thin vertical pipes, stools/bins.
    col_r = _u(r, (6,), 0.12, 0.6)
    col_xy = _push_xy(to_rig(inside(r, 6, 0.7)), keep + col_r + _u(r, (6,), 0.0, 1.0))
    pipe_r = _u(r, (5,), 0.015, 0.08)
    pipe_xy = _push_xy(to_rig(inside(r, 5, 0.2)), keep + pipe_r + 0.02)
    st_r = _u(r, (5,), 0.15, 0.4)
    st_xy = _push_xy(to_rig(inside(r, 5, 0.5)), keep + st_r + 0.02)
    cylinder_xy = jnp.concatenate([col_xy, pipe_xy, st_xy])
    cylinder_radius = jnp.concatenate([col_r, pipe_r, st_r])
    cylinder_z0 = jnp.full((NUM_CYLINDERS,), floor - 0.05)
    cylinder_z1 = jnp.concatenate([jnp.full((11,), ceiling + 0.05),
                                   floor + _u(r, (5,), 0.3, 1.0)])
    cylinder_active = jnp.concatenate([_count_mask(r, 6, 0, 6),
                                       _count_mask(r, 5, 0, 5),
                                       _count_mask(r, 5, 0, 5)])

    # Capsules: pipes along the ceiling, the lamps' cords, slanted rails.
    pz = ceiling - _u(r, (8,), 0.05, 0.8)
    p_pos = _u(r, (8,), -1.0, 1.0)
    p_ax = _bernoulli(r, 0.5, (8,))
    ones = jnp.ones(8)
    pa_room = jnp.where(p_ax[:, None], jnp.stack([-half_xy[0] * ones, p_pos * half_xy[1]], -1),
                        jnp.stack([p_pos * half_xy[0], -half_xy[1] * ones], -1))
    pb_room = jnp.where(p_ax[:, None], jnp.stack([half_xy[0] * ones, p_pos * half_xy[1]], -1),
                        jnp.stack([p_pos * half_xy[0], half_xy[1] * ones], -1))
    pipe_a = jnp.concatenate([to_rig(pa_room), pz[:, None]], -1)
    pipe_b = jnp.concatenate([to_rig(pb_room), pz[:, None]], -1)
    pipe_rad = _logu(r, (8,), 0.01, 0.15)
    cord_a = jnp.concatenate([lamp_xy, (lamp_z + lamp_r)[:, None]], -1)
    cord_b = jnp.concatenate([lamp_xy, jnp.full((6, 1), ceiling)], -1)
    rail_a = jnp.concatenate([to_rig(inside(r, 2, 0.3)), jnp.full((2, 1), floor)], -1)
    rail_b = jnp.concatenate([to_rig(inside(r, 2, 0.3)), jnp.full((2, 1), ceiling)], -1)
    capsule_a = jnp.concatenate([pipe_a, cord_a, rail_a])
    capsule_b = jnp.concatenate([pipe_b, cord_b, rail_b])
    capsule_radius = jnp.concatenate([pipe_rad, _u(r, (6,), 0.004, 0.012),
                                      _u(r, (2,), 0.02, 0.06)])
    capsule_active = jnp.concatenate([_count_mask(r, 8, 1, 8), lamp_on,
                                      _count_mask(r, 2, 0, 2)])

    scene = empty_scene().replace(
        plane_height=jnp.stack([floor, ceiling]),
        plane_active=jnp.zeros(NUM_PLANES, bool),
        room_centre=room_centre, room_half=room_half, room_yaw=room_yaw,
        room_active=jnp.asarray(True),
        box_centre=box_centre, box_half=box_half, box_yaw=box_yaw, box_active=box_active,
        sphere_centre=sphere_centre, sphere_radius=sphere_radius, sphere_active=sphere_active,
        cylinder_xy=cylinder_xy, cylinder_radius=cylinder_radius, cylinder_z0=cylinder_z0,
        cylinder_z1=cylinder_z1, cylinder_active=cylinder_active, capsule_a=capsule_a,
        capsule_b=capsule_b, capsule_radius=capsule_radius, capsule_active=capsule_active,
        **_lighting(r, indoor=True))
    spec = jnp.concatenate([
        _spec(2, (0.0, 1.0), (0.0, 0.3), (0.4, 0.9)),  # planes (unused indoors)
        _spec(1, (0.0, 1.0), (0.0, 0.45), (0.45, 0.95)),  # room walls
        _spec(8, (0.0, 1.0), (0.2, 0.9), (0.25, 0.95)),  # furniture
        _spec(6, (0.02, 0.12), (0.2, 0.6), (0.3, 0.85)),  # beams
        _spec(4, (0.0, 1.0), (0.0, 0.3), (0.5, 0.95)),  # ducts
        _spec(6, (0.0, 1.0), (0.2, 0.8), (0.2, 0.9)),  # shelves
        _spec(6, (0.08, 0.17), (0.0, 0.5), (0.85, 1.0)),  # lamps
        _spec(6, (0.0, 1.0), (0.5, 1.0), (0.5, 1.0)),  # balls
        _spec(16, (0.0, 1.0), (0.0, 0.7), (0.2, 0.9)),  # columns, pipes, stools
        _spec(16, (0.0, 1.0), (0.0, 0.5), (0.1, 0.8)),  # pipes, cords, rails
    ])
    return scene, spec, height


def _distances(scene: Scene) -> Array:
    """(P,) rough distance of each primitive from the reference point (sets texture scale)."""
    # The cameras see the ground beyond roughly 7 times its depth (under a 195 deg lens).
    planes = jnp.abs(scene.plane_height) * jnp.array([6.0, 1.0])
    room = jnp.min(scene.room_half)[None]
    boxes = jnp.maximum(jnp.linalg.norm(scene.box_centre, axis=-1)
                        - jnp.linalg.norm(scene.box_half, axis=-1), 0.5 + 0.3
                        * jnp.min(scene.box_half, -1))
    spheres = jnp.linalg.norm(scene.sphere_centre, axis=-1) - scene.sphere_radius
    cyl = jnp.linalg.norm(scene.cylinder_xy, axis=-1) - scene.cylinder_radius
    caps = _segment_distance(scene.capsule_a, scene.capsule_b) - scene.capsule_radius
    return jnp.maximum(jnp.concatenate([planes, room, boxes, spheres, cyl, caps]), 0.5)


def _enforce_clearance(scene: Scene, clear: Clearance) -> Scene:
    """Deactivate every primitive that still reaches into the rig's inflated keep-out zone."""
    bx_rho = jnp.linalg.norm(scene.box_centre[:, :2], axis=-1)
    bad_box = _keepout_violation(bx_rho, jnp.linalg.norm(scene.box_half[:, :2], axis=-1),
                                 scene.box_centre[:, 2] - scene.box_half[:, 2],
                                 scene.box_centre[:, 2] + scene.box_half[:, 2], clear)
    sp_rho = jnp.linalg.norm(scene.sphere_centre[:, :2], axis=-1)
    bad_sp = _keepout_violation(sp_rho, scene.sphere_radius,
                                scene.sphere_centre[:, 2] - scene.sphere_radius,
                                scene.sphere_centre[:, 2] + scene.sphere_radius, clear)
    cy_rho = jnp.linalg.norm(scene.cylinder_xy, axis=-1)
    bad_cy = _keepout_violation(cy_rho, scene.cylinder_radius, scene.cylinder_z0,
                                scene.cylinder_z1, clear)
    bad_ca = _capsule_violation(scene.capsule_a, scene.capsule_b, scene.capsule_radius, clear)
    return scene.replace(box_active=scene.box_active & ~bad_box,
                         sphere_active=scene.sphere_active & ~bad_sp,
                         cylinder_active=scene.cylinder_active & ~bad_cy,
                         capsule_active=scene.capsule_active & ~bad_ca)


def _translate(scene: Scene, ref: Array) -> Scene:
    """Move a scene built around the origin to be centred on the rig reference point ``ref``."""
    return scene.replace(
        plane_height=scene.plane_height + ref[2], room_centre=scene.room_centre + ref,
        box_centre=scene.box_centre + ref, sphere_centre=scene.sphere_centre + ref,
        cylinder_xy=scene.cylinder_xy + ref[:2], cylinder_z0=scene.cylinder_z0 + ref[2],
        cylinder_z1=scene.cylinder_z1 + ref[2], capsule_a=scene.capsule_a + ref,
        capsule_b=scene.capsule_b + ref)


@functools.partial(jax.jit, static_argnames=("clearance",))
def _random_scene(key: Array, indoor: Array, clearance: Clearance, reference: Array) -> Scene:
    # Both generators run and the style picks one, so a single compile serves both styles.
    k_geo, k_mat = jax.random.split(key)
    s_in, spec_in, _ = _indoor(k_geo, clearance)
    s_out, spec_out, _ = _outdoor(k_geo, clearance)
    scene = jax.tree_util.tree_map(lambda a, b: jnp.where(indoor, a, b), s_in, s_out)
    spec = jnp.where(indoor, spec_in, spec_out)
    scene = _enforce_clearance(scene, clearance)
    scene = _with_materials(scene, k_mat, _distances(scene), spec)
    return _translate(scene, reference)


def random_scene(key: Array, style: str, clearance: Clearance, reference) -> Scene:
    """A random ``style`` ('indoor' or 'outdoor') scene around ``reference`` (3,) in the rig frame.

    Nothing comes within ``clearance.margin`` metres of the rig's keep-out cylinder (see
    :func:`rig_clearance`). Jitted; one compile per clearance serves every key and style.
    """
    if style not in STYLES:
        raise ValueError(f"unknown scene style {style!r}; expected one of {STYLES}")
    return _random_scene(key, jnp.asarray(style == "indoor"), clearance,
                         jnp.asarray(reference, jnp.float32))
