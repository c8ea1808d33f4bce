"""Lens draws: the same rig seen through other fisheye lenses, for data that covers real lenses.

A network trained on one lens learns that lens's image layout: where the field of view ends,
how fast resolution falls towards the rim, how large the mask is. Real rigs use lenses from
180 to well over 220 degrees, calibrated as equidistant, Kannala-Brandt or Double Sphere
cameras. :func:`draw_lens` replaces one camera's lens by a random one of a given model, keeping
the camera's pose, image size and principal point:

* the field of view (full cone angle) is drawn uniformly in ``fov_deg`` (180-240 degrees);
* the image circle, the radius at which the field of view ends, is a fraction ``circle`` of
  half the shorter image side (a lens that fills the sensor, or leaves a black rim);
* the model's shape parameters are drawn in ranges where the projection rises monotonically
  over the whole field of view (Kannala-Brandt: ``k1``, ``k2``; Double Sphere: ``xi``,
  ``alpha``), and the focal length then follows from the circle: ``f = R / m(theta_max)``,
  ``m`` the model's radius at unit focal length.

Pure and traceable for a given model (the model fixes the camera's pytree type); the rig-level
edge :func:`lens_variant_rig` draws one model for the rig and one lens per camera, each camera
from its own sub-key. Used by ``gijax render --lens``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from gijax.checks import bad_field
from gijax.geometry import cameras as cam_lib
from gijax.geometry.rig import Rig, with_occlusion_masks

Array = jax.Array

LENS_MODELS = ("equidistant", "kb", "ds")


@dataclasses.dataclass(frozen=True)
class LensDraw:
    """Ranges of a lens draw (each drawn uniformly).

    Attributes:
      fov_deg: full field of view, degrees.
      circle: radius of the field-of-view edge, as a fraction of half the shorter image side.
      kb_k1, kb_k2: Kannala-Brandt coefficients (k3 = k4 = 0); within these ranges the radius
        rises over 240 degrees (its slope stays above 0.3).
      ds_xi, ds_alpha: Double Sphere parameters; within these ranges the model is valid beyond
        240 degrees (its own limit, ``gijax.geometry.field_of_view.model_limit``, is at least
        249 degrees).
    """

    fov_deg: tuple = (180.0, 240.0)
    circle: tuple = (0.85, 1.0)
    kb_k1: tuple = (-0.03, 0.03)
    kb_k2: tuple = (-0.003, 0.003)
    ds_xi: tuple = (-0.15, 0.05)
    ds_alpha: tuple = (0.5, 0.6)

    def __post_init__(self):
        lo, hi = self.fov_deg
        if not 0.0 < lo <= hi < 360.0:
            raise bad_field("LensDraw", "fov_deg", "(low, high) with 0 < low <= high < 360",
                            self.fov_deg)
        lo, hi = self.circle
        if not 0.0 < lo <= hi:
            raise bad_field("LensDraw", "circle", "(low, high) with 0 < low <= high",
                            self.circle)


def unit_radius(model: str, shape: dict, theta: Array) -> Array:
    """The model's image radius at unit focal length for a ray ``theta`` (rad) off the axis.

    ``shape`` holds the model's shape parameters: none for 'equidistant', ``k1``..``k4`` for
    'kb' (missing ones are zero), ``xi`` and ``alpha`` for 'ds'. The radius is the camera
    model's own projection (unit focal length, principal point at the origin) of the ray
    ``(sin theta, 0, cos theta)``, so a lens draw and the camera it makes can never disagree.
    """
    if model not in LENS_MODELS:
        raise ValueError(f"lens model {model!r} is not drawn; expected one of {LENS_MODELS}")
    theta = jnp.asarray(theta)
    dtype = jnp.result_type(theta, *shape.values(), jnp.float32)
    one, zero = jnp.ones((), dtype), jnp.zeros((), dtype)
    params = dict(shape)
    if model == "kb":
        params = {n: params.get(n, zero) for n in ("k1", "k2", "k3", "k4")}
    cam = cam_lib.CAMERA_MODELS[model](fx=one, fy=one, cx=zero, cy=zero, **params,
                                       fov=jnp.asarray(2.0 * jnp.pi, dtype), width=1, height=1)
    ray = jnp.stack([jnp.sin(theta), jnp.zeros_like(theta), jnp.cos(theta)], axis=-1)
    pixels, _ = cam_lib.project(cam, ray.astype(dtype))
    return pixels[..., 0]


def _uniform(key, lo_hi, dtype):
    return jax.random.uniform(key, (), dtype, lo_hi[0], lo_hi[1])


def draw_lens(key: Array, cam, model: str, draw: LensDraw = LensDraw()):
    """``cam`` with a random lens of ``model`` ('equidistant', 'kb' or 'ds'): same image size
    and principal point, field of view, image circle and shape drawn from ``draw``."""
    if model not in LENS_MODELS:
        raise ValueError(f"lens model {model!r} is not drawn; expected one of {LENS_MODELS}")
    dtype = jnp.result_type(cam.cx, jnp.float32)
    k_fov, k_circle, k_a, k_b = jax.random.split(key, 4)
    fov = jnp.deg2rad(_uniform(k_fov, draw.fov_deg, dtype))
    radius = _uniform(k_circle, draw.circle, dtype) * 0.5 * min(cam.width, cam.height)
    if model == "kb":
        shape = {"k1": _uniform(k_a, draw.kb_k1, dtype), "k2": _uniform(k_b, draw.kb_k2, dtype),
                 "k3": jnp.zeros((), dtype), "k4": jnp.zeros((), dtype)}
    elif model == "ds":
        shape = {"xi": _uniform(k_a, draw.ds_xi, dtype),
                 "alpha": _uniform(k_b, draw.ds_alpha, dtype)}
    else:
        shape = {}
    focal = radius / unit_radius(model, shape, 0.5 * fov)
    cls = cam_lib.CAMERA_MODELS[model]
    return cls(fx=focal, fy=focal, cx=jnp.asarray(cam.cx, dtype), cy=jnp.asarray(cam.cy, dtype),
               **shape, fov=fov, width=cam.width, height=cam.height)


def lens_variant_rig(seed: int, rig: Rig, model: str = "random",
                     draw: LensDraw = LensDraw()) -> tuple[Rig, str]:
    """``rig`` with every camera's lens drawn (one model for the rig, ``model`` or drawn from
    :data:`LENS_MODELS` when 'random'; camera ``i`` draws from sub-key ``i``), and the model.

    Masks belong to a lens: a rig with a body (occluder) gets its masks derived again for the
    new lenses; masks without a body to derive them from are dropped (all pixels valid).
    """
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"lens seed must be a non-negative integer; found {seed!r}")
    if model != "random" and model not in LENS_MODELS:
        raise ValueError(f"lens model {model!r}: expected 'random' or one of {LENS_MODELS}")
    key = jax.random.PRNGKey(int(seed))
    k_model, k_cams = jax.random.split(key)
    if model == "random":
        model = LENS_MODELS[int(jax.random.randint(k_model, (), 0, len(LENS_MODELS)))]
    keys = jax.random.split(k_cams, rig.num_cameras)
    cams = tuple(draw_lens(keys[i], c, model, draw) for i, c in enumerate(rig.cameras))
    out = rig.replace(cameras=cams)
    if rig.occluder is not None:
        out = with_occlusion_masks(out)
    else:
        out = out.replace(masks=tuple(None for _ in cams))
    return out, model
