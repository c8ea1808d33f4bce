"""Multi-fisheye samples with exact labels, rendered by pure functions of a scene and a key.

One jitted function renders every camera of a rig and the ground-truth panorama from a
:class:`gijax.render.scene.Scene`; the scene's shapes are fixed, so one compile per rig and
panorama size serves every seed. Rays are processed in fixed-size chunks (``lax.map``) so that
paper-size rigs (3 x 1024 x 1024 pixels) fit in memory.

Everything here is a pure function of its arguments: the randomness (the scene, the cameras'
exposure and sensor noise) comes from a PRNG key through named draws
(:mod:`gijax.render.named_draws`), and the outputs are device arrays. The rig, the panorama and
the chunk size are static configuration. Integer seeds and numpy outputs are the business of
:mod:`gijax.render.render`.

Labels:

* camera ``distances`` (N, h, w): metres from the camera centre along each pixel's unit ray to
  the first surface, the rig's own body included (it is a real surface in front of the lens);
  1e6 for sky and for pixels outside the lens image.
* ``masks`` (N, h, w): 1 where the pixel sees the world (inside the lens image, not the rig's
  body, and inside the rig's own mask if it has one).
* ``pano_distance`` (H, W): metres from the rig's reference point along each panorama ray
  (:func:`gijax.geometry.panorama_frame.panorama_rays`: the panorama oriented by the rig's
  panorama frame); the rig's body is not in it.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from gijax.geometry import cameras as cam_lib
from gijax.geometry.occluder import FAR, cylinder_intersection
from gijax.geometry.panorama import Panorama, ray_grid
from gijax.geometry.panorama_frame import panorama_rotation
from gijax.geometry.rig import Rig, is_homogeneous
from gijax.render.clearance import rig_clearance
from gijax.render.named_draws import named_key
from gijax.render.random_scene import random_scene
from gijax.render.raycast import trace
from gijax.render.scene import NUM_PRIMITIVES, SKY_ID, Scene
from gijax.render.shading import RIG_BODY_GREY, expose, random_exposure, shade
from gijax.render.texture import albedo, sky

Array = jax.Array
DEFAULT_CHUNK = 32768


def _chunked(fn, chunk: int, *arrays):
    """``fn`` over the leading axis of ``arrays`` in chunks of ``chunk`` rows (sequentially)."""
    m = arrays[0].shape[0]
    chunk = min(chunk, m)
    n = -(-m // chunk)
    pad = n * chunk - m

    def prep(a):
        a = jnp.pad(a, [(0, pad)] + [(0, 0)] * (a.ndim - 1), mode="edge")
        return a.reshape((n, chunk) + a.shape[1:])

    out = jax.lax.map(lambda xs: fn(*xs), tuple(prep(a) for a in arrays))
    return jax.tree_util.tree_map(lambda o: o.reshape((n * chunk,) + o.shape[2:])[:m], out)


def _colour(scene: Scene, o: Array, d: Array, pixel_angle: Array, t: Array, normal: Array,
            pid: Array) -> Array:
    """Radiance (M, 3) of traced rays: textured, shaded surfaces and the sky."""
    hit = pid != SKY_ID
    idx = jnp.clip(pid, 0, NUM_PRIMITIVES - 1)
    mat = dict(colours=scene.mat_colours[idx], noise_freq=scene.mat_noise_freq[idx],
               pattern=scene.mat_pattern[idx], pattern_freq=scene.mat_pattern_freq[idx],
               pattern_axis=scene.mat_pattern_axis[idx],
               pattern_strength=scene.mat_pattern_strength[idx], offset=scene.mat_offset[idx])
    t_hit = jnp.where(hit, t, 1.0)
    p = o + t_hit[:, None] * d
    rad = shade(albedo(p, mat, t_hit * pixel_angle), normal, d, scene.light_dir,
                scene.light_strength, scene.ambient)
    return jnp.where(hit[:, None], rad, sky(d, scene, pixel_angle))


def trace_distance(scene: Scene, o: Array, d: Array) -> Array:
    """Distance (M,) to the first surface (FAR for sky) of rays ``o`` + t ``d`` (M, 3)."""
    return trace(scene, o, d)[0]


def camera_rays(cam, rot: Array, trans: Array) -> dict:
    """Per-pixel rays of one camera, flattened to M = h * w: rig-frame unit directions (M, 3),
    lens validity (M,), pixel angle (M,) radians and rim position (M,) (0 centre, 1 at fov/2)."""
    px = cam_lib.pixel_grid(cam.width, cam.height).reshape(-1, 2)
    shifts = jnp.array([[[0.0, 0.0]], [[1.0, 0.0]], [[0.0, 1.0]]], px.dtype)
    all_rays, all_ok = cam_lib.unproject(cam, px[None] + shifts)
    ray_c, right, down = all_rays
    ok, ok_r, ok_d = all_ok
    step = jnp.maximum(jnp.linalg.norm(right - ray_c, axis=-1),
                       jnp.linalg.norm(down - ray_c, axis=-1))
    fallback = 1.0 / jnp.maximum(cam.fx, 1e-6)
    angle = jnp.where(ok_r & ok_d & ok, step, fallback)
    theta = jnp.arctan2(jnp.linalg.norm(ray_c[:, :2], axis=-1), ray_c[:, 2])
    half_fov = jnp.minimum(cam.fov, 2 * jnp.pi) / 2
    return dict(dirs=ray_c @ rot.T, valid=ok, pixel_angle=angle, rim=theta / half_fov)


def _body(rig: Rig, origin: Array, dirs: Array) -> tuple[Array, Array]:
    """Distance (M,) to the rig's body (FAR if none or missed) and its dark grey shade (M, 3)."""
    if rig.occluder is None:
        return jnp.full(dirs.shape[:1], FAR, dirs.dtype), jnp.zeros_like(dirs)
    t, normal = cylinder_intersection(rig.occluder, origin, dirs)
    lit = shade(jnp.full_like(dirs, RIG_BODY_GREY), normal, dirs,
                jnp.array([0.0, 0.0, 1.0]), jnp.asarray(0.4), jnp.asarray(0.8))
    return t, lit


def _all_camera_rays(rig: Rig) -> list[dict]:
    """:func:`camera_rays` of every camera (vmapped when the cameras share model and size)."""
    if is_homogeneous(rig):
        cams = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *rig.cameras)
        stacked = jax.vmap(camera_rays)(cams, rig.rotations, rig.translations)
        return [jax.tree_util.tree_map(lambda a: a[i], stacked) for i in range(rig.num_cameras)]
    return [camera_rays(c, rig.rotations[i], rig.translations[i])
            for i, c in enumerate(rig.cameras)]


def _pad_to(a: Array, rows: int) -> Array:
    return jnp.pad(a, [(0, rows - a.shape[0])] + [(0, 0)] * (a.ndim - 1), mode="edge")


def _trace_and_shade(scene: Scene, chunk: int, o: Array, d: Array, angle: Array,
                     coloured: Array) -> tuple[Array, Array]:
    """Distances (M,) of all rays and radiance (M, 3) where ``coloured`` (M / chunk,) says so.

    The rays are traced in chunks by one compiled ray caster; chunks that only need distances
    (the panorama's) skip the texturing.
    """
    m = o.shape[0]
    n = m // chunk

    def one(args):
        o_c, d_c, a_c, want = args
        t, normal, pid = trace(scene, o_c, d_c)
        rad = jax.lax.cond(want, lambda: _colour(scene, o_c, d_c, a_c, t, normal, pid),
                           lambda: jnp.zeros_like(d_c))
        return t, rad

    t, rad = jax.lax.map(one, (o.reshape(n, chunk, 3), d.reshape(n, chunk, 3),
                               angle.reshape(n, chunk), coloured))
    return t.reshape(m), rad.reshape(m, 3)


def render_views(scene: Scene, rig: Rig, key: Array, pano: Panorama,
                 chunk: int = DEFAULT_CHUNK, noise: bool = True) -> dict:
    """Render every camera of ``rig`` and the panorama distance at its reference point.

    Returns a dict of device arrays: ``images`` float32 (N, h, w, 3) in [0, 1], ``distances``
    float32 (N, h, w) metres, ``masks`` bool (N, h, w), ``pano_distance`` float32 (H, W) metres.
    A rig whose cameras differ in size gets per-camera lists instead of stacked arrays.
    """
    # The panorama's rays enter as an argument: built inside the compiled function they would be
    # constant-folded element by element at compile time, which is slow for large panoramas.
    return _render_views(scene, rig, key, _pano_rays(pano), pano.shape, chunk, noise)


@functools.lru_cache(maxsize=8)
def _pano_rays(pano: Panorama) -> Array:
    # Concrete even when first asked for inside a trace: the cache must never hold a tracer.
    with jax.ensure_compile_time_eval():
        return jax.jit(ray_grid, static_argnums=0)(pano).reshape(-1, 3)


@functools.partial(jax.jit, static_argnames=("pano_shape", "chunk", "noise"))
def _render_views(scene: Scene, rig: Rig, key: Array, pano_dirs: Array, pano_shape: tuple,
                  chunk: int, noise: bool) -> dict:
    n = rig.num_cameras
    exposure = random_exposure(named_key(key, "exposure"), n)
    rays = _all_camera_rays(rig)
    sizes = [r["dirs"].shape[0] for r in rays]
    m_cam = sum(sizes)
    # Panorama-frame rays into the rig frame (the cached rays do not depend on the rig).
    pano_dirs = pano_dirs @ panorama_rotation(rig).astype(pano_dirs.dtype).T
    m_pano = pano_dirs.shape[0]
    chunk = min(chunk, max(m_cam, m_pano))
    rows_cam = -(-m_cam // chunk) * chunk
    rows_pano = -(-m_pano // chunk) * chunk
    # All camera pixels as one flat ray list (M = sum of h * w), each knowing its camera.
    cam_id = jnp.concatenate([jnp.full((s,), i, jnp.int32) for i, s in enumerate(sizes)])
    cam = {k: jnp.concatenate([r[k] for r in rays]) for k in rays[0]}
    cam_origin = rig.translations[cam_id]
    origins = jnp.concatenate([_pad_to(cam_origin, rows_cam),
                               jnp.broadcast_to(rig.reference, (rows_pano, 3))])
    dirs = jnp.concatenate([_pad_to(cam["dirs"], rows_cam), _pad_to(pano_dirs, rows_pano)])
    angle = jnp.concatenate([_pad_to(cam["pixel_angle"], rows_cam),
                             jnp.ones(rows_pano, dirs.dtype)])
    coloured = jnp.arange((rows_cam + rows_pano) // chunk) < rows_cam // chunk
    dist, radiance = _trace_and_shade(scene, chunk, origins, dirs, angle, coloured)
    dist_cam, radiance = dist[:m_cam], radiance[:m_cam]
    t_body, body_rgb = _body(rig, cam_origin, cam["dirs"])
    body = t_body < dist_cam
    radiance = jnp.where(body[:, None], body_rgb, radiance)
    dist_cam = jnp.where(body, t_body, dist_cam)
    rgb = expose(radiance, exposure, cam_id, cam["rim"], named_key(key, "noise"), noise)
    valid = cam["valid"]
    mask = valid & ~body
    rig_masks = [jnp.ones((s,), bool) if m is None else jnp.asarray(m).reshape(-1) > 0.5
                 for m, s in zip(rig.masks, sizes)]
    mask = mask & jnp.concatenate(rig_masks)
    images = jnp.where(valid[:, None], rgb, 0.0)
    distances = jnp.where(valid, dist_cam, FAR)
    out = dict(pano_distance=dist[rows_cam:rows_cam + m_pano].reshape(pano_shape))
    if is_homogeneous(rig):
        shape = (n, rig.cameras[0].height, rig.cameras[0].width)
        out.update(images=images.reshape(shape + (3,)), distances=distances.reshape(shape),
                   masks=mask.reshape(shape))
        return out
    bounds = np.cumsum([0] + sizes)
    split = lambda a, i: a[bounds[i]:bounds[i + 1]].reshape(  # noqa: E731
        (rig.cameras[i].height, rig.cameras[i].width) + a.shape[1:])
    out.update(images=[split(images, i) for i in range(n)],
               distances=[split(distances, i) for i in range(n)],
               masks=[split(mask, i) for i in range(n)])
    return out


def render_panorama_distance(scene: Scene, reference: Array, pano: Panorama,
                             chunk: int = DEFAULT_CHUNK, rotation=None) -> Array:
    """(H, W) distance in metres from ``reference`` (3,) along every panorama ray; ``rotation``
    (3, 3) is the panorama-to-rig rotation (default the identity: pole on the rig's +z)."""
    dirs = _pano_rays(pano)
    if rotation is not None:
        dirs = dirs @ jnp.asarray(rotation, dirs.dtype).T
    return _panorama_distance(scene, jnp.asarray(reference, jnp.float32), dirs,
                              chunk).reshape(pano.shape)


@functools.partial(jax.jit, static_argnames=("chunk",))
def _panorama_distance(scene: Scene, reference: Array, dirs: Array, chunk: int) -> Array:
    ref = jnp.broadcast_to(reference.astype(dirs.dtype), dirs.shape)
    return _chunked(functools.partial(trace_distance, scene), chunk, ref, dirs)


def sample_keys(key: Array) -> tuple[Array, Array]:
    """The keys of a sample's scene and of its views (exposure, sensor noise)."""
    return named_key(key, "scene"), named_key(key, "views")


def random_sample_scene(rig: Rig, key: Array, style: str = "mixed") -> Scene:
    """The random scene of the sample ``key`` around ``rig`` (clear of its cameras and body by
    0.5 m); ``style`` as :func:`gijax.render.random_scene.random_scene`."""
    scene_key, _ = sample_keys(key)
    return random_scene(scene_key, style, rig_clearance(rig), rig.reference)


def random_sample(rig: Rig, key: Array, pano: Panorama = Panorama.hemisphere(160, 640),
                  style: str = "mixed", noise: bool = True, chunk: int = DEFAULT_CHUNK) -> dict:
    """One random training sample for ``rig``, a pure function of ``key``: its scene
    (:func:`random_sample_scene`) rendered by :func:`render_views`, device arrays."""
    _, views_key = sample_keys(key)
    return render_views(random_sample_scene(rig, key, style), rig, views_key, pano, chunk, noise)
