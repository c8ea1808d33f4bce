"""Multi-camera rigs: cameras, camera-to-rig poses, a reference point, masks, an occluder, and
the orientation of the rig's panorama.

Rig frame: for the built-in layouts +z is the viewing axis shared by the cameras, x and y span
the mounting plane; like the camera frame it is right-handed (x right, y down, z forward when
seen from behind the cameras). Poses are camera-to-rig: a point ``p_c`` in camera i's frame is
``R_i @ p_c + t_i`` in the rig frame, so ``t_i`` is camera i's centre. The panorama's frame
(its pole and longitude origin) is the rotation ``panorama_rotation`` (panorama-to-rig; the
identity puts the pole on the rig's +z axis), see :mod:`gijax.geometry.panorama_frame`.

A :class:`Rig` is a pytree: its poses, reference point, intrinsics and masks are leaves, so every
function of a rig here is traceable (jit, vmap, grad in those leaves; camera indices and image
sizes are static), except the reports :func:`pairwise_baselines` (NumPy) and
:func:`describe_rig` (text), and the structural query :func:`is_homogeneous` (a Python bool).
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from gijax.geometry import cameras as cam_lib
from gijax.geometry.occluder import FAR, Cylinder, cylinder_hit

Array = jax.Array


@dataclasses.dataclass(frozen=True)
class Rig:
    """N cameras with camera-to-rig poses; a pytree (names are static, the rest are leaves).

    Attributes:
      cameras: one camera pytree per camera (models may differ).
      rotations: (N, 3, 3) camera-to-rig rotations.
      translations: (N, 3) camera centres in the rig frame, metres.
      reference: (3,) the panorama centre in the rig frame.
      panorama_rotation: (3, 3) panorama-to-rig rotation: its columns are the panorama frame's
        x (longitude 0), y and z (the pole, row 0) axes in the rig frame.
      masks: per camera ``None`` (all valid) or an (H, W) array, 1 = valid, 0 = self-occluded.
      occluder: the rig's body (or ``None``), used for rendering and to derive masks.
      names: camera names (static).
    """

    cameras: tuple
    rotations: Array
    translations: Array
    reference: Array
    masks: tuple
    occluder: Optional[Cylinder] = None
    names: tuple = ()
    # None (a rig built without one) reads as the identity; make_rig always sets it.
    panorama_rotation: Optional[Array] = None

    @property
    def num_cameras(self) -> int:
        return len(self.cameras)

    def replace(self, **kw) -> "Rig":
        return dataclasses.replace(self, **kw)


jax.tree_util.register_dataclass(
    Rig,
    data_fields=["cameras", "rotations", "translations", "reference", "masks", "occluder",
                 "panorama_rotation"],
    meta_fields=["names"],
)


def make_rig(cameras: Sequence, rotations, translations, reference=None, masks=None,
             occluder: Optional[Cylinder] = None, names: Sequence[str] | None = None,
             dtype=jnp.float32, panorama_rotation=None) -> Rig:
    n = len(cameras)
    if n == 0:
        raise ValueError("a rig needs at least one camera; found 0")
    rotations = jnp.asarray(rotations, dtype).reshape(n, 3, 3)
    translations = jnp.asarray(translations, dtype).reshape(n, 3)
    reference = jnp.zeros(3, dtype) if reference is None else jnp.asarray(reference, dtype)
    masks = tuple([None] * n) if masks is None else tuple(masks)
    if len(masks) != n:
        raise ValueError(f"rig has {n} cameras but {len(masks)} masks")
    names = tuple(names) if names is not None else tuple(f"cam{i}" for i in range(n))
    pano_rot = (jnp.eye(3, dtype=dtype) if panorama_rotation is None
                else jnp.asarray(panorama_rotation, dtype).reshape(3, 3))
    return Rig(tuple(cameras), rotations, translations, reference, masks, occluder, names,
               pano_rot)


def rig_to_camera(rig: Rig, i: int, points: Array) -> Array:
    """Rig-frame points (..., 3) into camera i's frame: R_i^T (p - t_i)."""
    return (points - rig.translations[i]) @ rig.rotations[i]


def camera_to_rig(rig: Rig, i: int, points: Array) -> Array:
    """Camera i's frame points (..., 3) into the rig frame: R_i p + t_i."""
    return points @ rig.rotations[i].T + rig.translations[i]


def is_homogeneous(rig: Rig) -> bool:
    """True when all cameras share model and image size (so they can be stacked and vmapped)."""
    first = rig.cameras[0]
    same = all(type(c) is type(first) and (c.width, c.height) == (first.width, first.height)
               for c in rig.cameras)
    masks_same = all(m is None for m in rig.masks) or all(
        m is not None and m.shape == (first.height, first.width) for m in rig.masks)
    return same and masks_same


def map_cameras(fn: Callable, rig: Rig, *per_camera) -> Array:
    """``stack([fn(cam_i, R_i, t_i, mask_i, *args_i) for i])``, vmapped when possible.

    ``per_camera`` arrays carry a leading camera axis. ``mask_i`` is an (H, W) array of ones
    where the rig has no mask for that camera. A rig whose cameras differ in model or size is
    handled by a Python loop over cameras (the camera count is static either way).
    """
    masks = [m if m is not None else jnp.ones((c.height, c.width), jnp.float32)
             for c, m in zip(rig.cameras, rig.masks)]
    if is_homogeneous(rig):
        cams = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *rig.cameras)
        return jax.vmap(fn)(cams, rig.rotations, rig.translations, jnp.stack(masks), *per_camera)
    outs = [fn(c, rig.rotations[i], rig.translations[i], masks[i], *[a[i] for a in per_camera])
            for i, c in enumerate(rig.cameras)]
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *outs)


def project_rig_points(rig: Rig, points: Array) -> tuple[Array, Array]:
    """Project rig-frame points (..., 3) into every camera: pixels (N, ..., 2), valid (N, ...).

    Validity includes the camera's self-occlusion mask (nearest pixel) where one is set.
    """

    def one(cam, rot, trans, mask, ):
        pc = (points - trans) @ rot
        px, ok = cam_lib.project(cam, pc)
        col = jnp.clip(jnp.round(px[..., 0]), 0, mask.shape[1] - 1).astype(jnp.int32)
        row = jnp.clip(jnp.round(px[..., 1]), 0, mask.shape[0] - 1).astype(jnp.int32)
        return px, ok & (mask[row, col] > 0.5)

    return map_cameras(one, rig)


def occlusion_mask(rig: Rig, i: int) -> Array:
    """Camera i's self-occlusion mask from the rig's occluder: (H, W) float32, 1 = sees the world.

    A pixel is occluded when its ray hits the occluder (at any distance); pixels outside the
    model's valid image are 0 as well.
    """
    return _occlusion_mask(rig.cameras[i], rig.rotations[i], rig.translations[i], rig.occluder)


@jax.jit
def _occlusion_mask(cam, rotation: Array, translation: Array, occluder) -> Array:
    # One compiled kernel per camera model and size instead of dozens of eager full-image ops.
    px = cam_lib.pixel_grid(cam.width, cam.height)
    ray_c, ok = cam_lib.unproject(cam, px)
    if occluder is None:
        return ok.astype(jnp.float32)
    dirs = ray_c @ rotation.T
    hit = cylinder_hit(occluder, translation, dirs)
    return (ok & (hit >= FAR)).astype(jnp.float32)


def with_occlusion_masks(rig: Rig) -> Rig:
    """The rig with every camera's mask derived from its occluder (see :func:`occlusion_mask`)."""
    return rig.replace(masks=tuple(occlusion_mask(rig, i) for i in range(rig.num_cameras)))


def scale_rig(rig: Rig, factor: float) -> Rig:
    """Every camera's image resized by ``factor`` (masks resampled by nearest neighbour)."""
    cams = tuple(cam_lib.scale_camera(c, factor) for c in rig.cameras)
    masks = []
    for c_old, c_new, m in zip(rig.cameras, cams, rig.masks):
        if m is None:
            masks.append(None)
            continue
        rows = np.clip(((np.arange(c_new.height) + 0.5) / factor - 0.5).round().astype(int), 0,
                       c_old.height - 1)
        cols = np.clip(((np.arange(c_new.width) + 0.5) / factor - 0.5).round().astype(int), 0,
                       c_old.width - 1)
        masks.append(jnp.asarray(m)[rows][:, cols])
    return rig.replace(cameras=cams, masks=tuple(masks))


def pairwise_baselines(rig: Rig) -> np.ndarray:
    """(N, N) distances between camera centres, metres, as NumPy float64 (a report of concrete
    values, not traced)."""
    t = np.asarray(rig.translations, np.float64)
    return np.linalg.norm(t[:, None] - t[None], axis=-1)


def describe_rig(rig: Rig) -> str:
    """A human-readable summary: cameras, models, intrinsics, positions, fields of view,
    pairwise baselines (metres), reference point and occluder (text from concrete values, not
    traced)."""
    from gijax.geometry.cameras import camera_params
    from gijax.geometry.field_of_view import describe_field_of_view

    lines = [f"rig with {rig.num_cameras} camera(s); poses camera-to-rig, metres"]
    for i, cam in enumerate(rig.cameras):
        pos = np.asarray(rig.translations[i], np.float64)
        axis = np.asarray(rig.rotations[i], np.float64)[:, 2]
        intr = ", ".join(f"{k}={v:.6g}" for k, v in camera_params(cam).items())
        fov = describe_field_of_view(cam)
        mask = rig.masks[i]
        valid = "" if mask is None else f", mask {float(np.asarray(mask).mean()) * 100:.1f}% valid"
        lines.append(f"  {rig.names[i]}: model {cam.MODEL}, {cam.width}x{cam.height} px, "
                     f"{fov}{valid}")
        lines.append(f"    intrinsics: {intr}")
        lines.append(f"    position [{pos[0]:+.4f}, {pos[1]:+.4f}, {pos[2]:+.4f}] m, optical axis "
                     f"[{axis[0]:+.3f}, {axis[1]:+.3f}, {axis[2]:+.3f}]")
    b = pairwise_baselines(rig)
    if rig.num_cameras > 1:
        lines.append("pairwise baselines (m):")
        lines.append("        " + "".join(f"{n:>10s}" for n in rig.names))
        for i, n in enumerate(rig.names):
            lines.append(f"  {n:>6s}" + "".join(f"{b[i, j]:10.4f}" for j in range(len(b))))
    ref = np.round(np.asarray(rig.reference, np.float64), 4) + 0.0   # no "-0.0000"
    lines.append(f"reference point: [{ref[0]:+.4f}, {ref[1]:+.4f}, {ref[2]:+.4f}] m")
    if rig.occluder is not None:
        o = rig.occluder
        lines.append(f"occluder: cylinder at ({float(o.x):+.4f}, {float(o.y):+.4f}), radius "
                     f"{float(o.radius):.4f} m, z {float(o.z_min):.3f}..{float(o.z_max):.3f} m")
    rot = np.eye(3) if rig.panorama_rotation is None else np.asarray(rig.panorama_rotation,
                                                                     np.float64)
    fmt = lambda v: "[" + ", ".join(f"{x + 0.0:+.3f}" for x in np.round(v, 3)) + "]"  # noqa: E731
    lines.append(f"panorama frame: pole (top row) {fmt(rot[:, 2])}, longitude 0 (middle column) "
                 f"{fmt(rot[:, 0])}, rig frame")
    return "\n".join(lines)
