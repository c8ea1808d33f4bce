"""Training-sample augmentations, deterministic per (seed, epoch, sample index).

Two kinds:

- The paper's random mask augmentation (REFERENCE section 5, NumPy): per sample, one random
  camera gets a random axis-aligned rectangle erased from its validity mask, covering 5-20 % of
  the image area with aspect ratio (height / width) 0.3-3.3, and its pixels outside the (new)
  mask are zeroed. The network thereby learns to cope with cameras partly blocked by parts of
  the robot it has never seen.
- :func:`augment_sample` (JAX, pure): the photometric degradations of a real camera
  (:mod:`gijax.data.photometric`) and random rig-body outlines (:mod:`gijax.data.body_masks`),
  each applied per camera with a probability and parameters drawn from ranges in a frozen
  :class:`AugmentConfig`. With every probability 0 (the default) it is the identity.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from gijax.data import photometric
from gijax.data.body_masks import BodyShape, body_occlusion, body_outline

AREA_FRACTION = (0.05, 0.20)
ASPECT = (0.3, 3.3)
def erase_rectangle(rng: np.random.Generator, height: int, width: int,
                    area_fraction=AREA_FRACTION, aspect=ASPECT) -> tuple[int, int, int, int]:
    """A random rectangle (top, left, rect_height, rect_width) inside a height x width image.

    The area fraction is uniform in ``area_fraction``; the aspect ratio (height / width) is
    log-uniform in ``aspect`` intersected with the ratios that fit the image at that area, so
    no retries are needed and the bounds hold up to rounding to whole pixels.
    """
    area = rng.uniform(*area_fraction) * height * width
    lo = max(aspect[0], area / width**2)
    hi = min(aspect[1], height**2 / area)
    if lo > hi:
        raise ValueError(f"no rectangle of area {area:.1f} px^2 and aspect {aspect} fits a "
                         f"{width}x{height} image")
    ratio = math.exp(rng.uniform(math.log(lo), math.log(hi)))
    rh = min(height, max(1, int(round(math.sqrt(area * ratio)))))
    rw = min(width, max(1, int(round(math.sqrt(area / ratio)))))
    top = int(rng.integers(0, height - rh + 1))
    left = int(rng.integers(0, width - rw + 1))
    return top, left, rh, rw


def augment_masks(images, masks, rng: np.random.Generator):
    """Erase a rectangle from one random camera's mask and zero that camera's invalid pixels.

    Args:
      images: per camera float (h, w, 3) (an (N, h, w, 3) array or a list).
      masks: per camera (h, w) in {0, 1}.
      rng: the sample's ``"erase"`` stream (:func:`gijax.random_streams.host_rng`).

    Returns new ``images``, ``masks`` (the inputs are not modified) and the chosen
    ``(camera, top, left, rect_height, rect_width)``.
    """
    cam = int(rng.integers(len(masks)))
    h, w = np.shape(masks[cam])
    top, left, rh, rw = erase_rectangle(rng, h, w)
    new_mask = np.array(masks[cam], copy=True)
    new_mask[top:top + rh, left:left + rw] = 0
    old_image = np.asarray(images[cam])
    new_image = old_image * (new_mask > 0)[..., None].astype(old_image.dtype)
    if isinstance(masks, np.ndarray) and isinstance(images, np.ndarray):
        masks = masks.copy()
        images = images.copy()
    else:
        masks = list(masks)
        images = list(images)
    masks[cam] = new_mask
    images[cam] = new_image
    return images, masks, (cam, top, left, rh, rw)


# -- photometric and body-outline augmentation (pure JAX)

@dataclasses.dataclass(frozen=True)
class AugmentConfig:
    """Probabilities (per camera and sample) and parameter ranges of :func:`augment_sample`.

    Every ``p_*`` is the probability that the camera gets that augmentation; ranges are
    ``(low, high)``, drawn uniformly (log-uniformly for ``exposure`` and ``gamma``). The
    defaults switch everything off; :data:`AUGMENT_PRESETS` holds the training settings. The
    config is hashable, so it can be a static argument of ``jit``.
    """

    p_vignetting: float = 0.0
    vignetting_strength: tuple = (0.0, 0.6)
    p_blur: float = 0.0
    blur_sigma: tuple = (0.3, 1.2)
    p_colour: float = 0.0
    exposure: tuple = (0.6, 1.6)
    white_balance: tuple = (0.85, 1.15)
    gamma: tuple = (0.8, 1.25)
    p_noise: float = 0.0
    shot_gain: tuple = (1e-4, 3e-3)
    read_std: tuple = (0.002, 0.01)
    p_jpeg: float = 0.0
    jpeg_quality: tuple = (40.0, 95.0)
    p_body: float = 0.0
    body: BodyShape = BodyShape()

    @property
    def blur_radius(self) -> int:
        """Kernel half-width: three standard deviations of the widest blur."""
        return max(1, math.ceil(3.0 * self.blur_sigma[1]))

    def is_identity(self) -> bool:
        return not any((self.p_vignetting, self.p_blur, self.p_colour, self.p_noise,
                        self.p_jpeg, self.p_body))


_PHOTOMETRIC = dict(p_vignetting=0.5, p_blur=0.3, p_colour=0.8, p_noise=0.8, p_jpeg=0.3)
AUGMENT_PRESETS = {
    "none": AugmentConfig(),
    # What a real camera does to the light; the masks are left alone.
    "photometric": AugmentConfig(**_PHOTOMETRIC),
    # The same plus random rig-body outlines entering a third of the views from the border.
    "photometric+body": AugmentConfig(**_PHOTOMETRIC, p_body=0.3),
}


def augment_preset(name: str) -> AugmentConfig:
    """The :data:`AUGMENT_PRESETS` entry ``name`` (ValueError naming the choices otherwise)."""
    if name not in AUGMENT_PRESETS:
        raise ValueError(f"unknown augmentation {name!r}; choose one of {sorted(AUGMENT_PRESETS)}")
    return AUGMENT_PRESETS[name]


def _uniform(key, lo_hi, shape=()):
    return jax.random.uniform(key, shape, jnp.float32, lo_hi[0], lo_hi[1])


def _log_uniform(key, lo_hi):
    return jnp.exp(_uniform(key, (math.log(lo_hi[0]), math.log(lo_hi[1]))))


# Each stage draws from its own named sub-key, so switching one stage on or off changes no
# other stage's draws.
_STAGES = ("vignetting", "blur", "colour", "noise", "jpeg", "body")


def _augment_camera(key, image, mask, centre, config: AugmentConfig):
    keys = {name: jax.random.fold_in(key, i) for i, name in enumerate(_STAGES)}
    h, w = image.shape[:2]

    def stage(name, p, fn, x):
        if p <= 0:                       # static: a stage that is off costs nothing
            return x
        k_on, k_params = jax.random.split(keys[name])
        on = jax.random.uniform(k_on) < p
        # A cond, not a select: a stage not drawn is not computed (under vmap it becomes a
        # select again, with the same values).
        return jax.lax.cond(on, fn, lambda _, y: y, k_params, x)

    def vignette(k, x):
        strength = _uniform(k, config.vignetting_strength)
        return photometric.vignetting(x, centre, 0.5 * min(h, w), strength)

    def blur(k, x):
        return photometric.gaussian_blur(x, _uniform(k, config.blur_sigma), config.blur_radius)

    def colour(k, x):
        k_e, k_g, k_w = jax.random.split(k, 3)
        red_blue = _uniform(k_w, config.white_balance, (2,))
        gains = jnp.stack([red_blue[0], 1.0, red_blue[1]])
        return photometric.exposure_white_balance(
            x, _log_uniform(k_e, config.exposure), gains, _log_uniform(k_g, config.gamma))

    def noise(k, x):
        k_s, k_r, k_n = jax.random.split(k, 3)
        return photometric.sensor_noise(k_n, x, _uniform(k_s, config.shot_gain),
                                        _uniform(k_r, config.read_std))

    def jpeg(k, x):
        return photometric.jpeg_compress(x, _uniform(k, config.jpeg_quality))

    # The order of a camera's pipeline: optics (vignetting, blur), sensor gain and colour,
    # sensor noise, then the encoder.
    x = image
    x = stage("vignetting", config.p_vignetting, vignette, x)
    x = stage("blur", config.p_blur, blur, x)
    x = stage("colour", config.p_colour, colour, x)
    x = stage("noise", config.p_noise, noise, x)
    x = stage("jpeg", config.p_jpeg, jpeg, x)
    if config.p_body > 0:
        k_on, k_shape = jax.random.split(keys["body"])
        on = jax.random.uniform(k_on) < config.p_body

        def occlude(k, x_m):
            x, m = x_m
            covered = body_occlusion(h, w, centre, body_outline(k, config.body))
            # Masks only lose pixels; the covered pixels are zeroed like any invalid pixel.
            return (x * (1.0 - covered)[..., None].astype(x.dtype),
                    m * (1.0 - covered).astype(m.dtype))

        x, mask = jax.lax.cond(on, occlude, lambda _, x_m: x_m, k_shape, (x, mask))
    return x, mask


def augment_sample(key: jax.Array, images: jax.Array, masks: jax.Array,
                   config: AugmentConfig, centres: jax.Array | None = None):
    """Augment one sample's cameras: images (N, H, W, 3) float RGB in [0, 1] and masks
    (N, H, W) -> new ``(images, masks)`` of the same shapes, images in [0, 1].

    Each camera draws its own parameters from ``key`` (camera i uses ``fold_in(key, i)``).
    ``centres`` (N, 2) are the principal points (u, v) in pixels that vignetting and body
    outlines are placed around (default: the image centres). Pure; ``jit`` it with ``config``
    static, ``vmap`` it over a batch of keys, images and masks. Masks only lose valid pixels.
    """
    images = jnp.asarray(images)
    masks = jnp.asarray(masks)
    n, h, w = images.shape[:3]
    if config.is_identity():
        return images, masks
    if centres is None:
        centres = jnp.broadcast_to(jnp.array([(w - 1) / 2.0, (h - 1) / 2.0], jnp.float32), (n, 2))
    centres = jnp.asarray(centres, jnp.float32)
    # A loop over the cameras rather than a vmap, so that each camera's stages stay conds
    # (computed only when drawn); the camera count is small and static.
    outs = [_augment_camera(jax.random.fold_in(key, i), images[i], masks[i], centres[i], config)
            for i in range(n)]
    return jnp.stack([o[0] for o in outs]), jnp.stack([o[1] for o in outs])
