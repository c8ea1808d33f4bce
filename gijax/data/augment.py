"""The paper's random mask augmentation (REFERENCE section 5), deterministic per seed.

Per sample, one random camera gets a random axis-aligned rectangle erased from its validity
mask, covering 5-20 % of the image area with aspect ratio (height / width) 0.3-3.3, and its
pixels outside the (new) mask are zeroed. The network thereby learns to cope with cameras
partly blocked by parts of the robot it has never seen.
"""

from __future__ import annotations

import math

import numpy as np

AREA_FRACTION = (0.05, 0.20)
ASPECT = (0.3, 3.3)
# Mixed into the random stream so that augmentation draws never coincide with shuffling draws.
_MASK_STREAM = 0x6D61736B


def augmentation_rng(seed: int, epoch: int, index: int) -> np.random.Generator:
    """The generator behind the augmentation of sample ``index`` in ``epoch``."""
    return np.random.default_rng([int(seed), int(epoch), int(index), _MASK_STREAM])


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
      rng: from :func:`augmentation_rng`.

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
