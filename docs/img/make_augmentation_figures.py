"""Draw docs/img/augment_*.png: one rendered fisheye before and after each augmentation.

Each picture uses the strong end of the augmentation's training range, so that the effect is
visible at the small size of the picture. Run from the repository root:

    python docs/img/make_augmentation_figures.py
"""

from __future__ import annotations

from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from gijax.data import photometric as ph
from gijax.data.body_masks import BodyShape, body_occlusion, body_outline
from gijax.geometry.layouts import builtin_rig
from gijax.geometry.rig import scale_rig
from gijax.render import render_sample

OUT = Path(__file__).resolve().parent
SCALE = 0.1875        # 1024 px synthetic fisheyes -> 192 px
SEED = 7


def _figures(image: jnp.ndarray, mask: jnp.ndarray, centre) -> dict:
    h, w = image.shape[:2]
    key = jax.random.PRNGKey(SEED)
    body = body_occlusion(h, w, centre, body_outline(key, BodyShape(wobble=0.15)))
    return {
        "noise": ("sensor noise, shot 3e-3, read 0.01",
                  ph.sensor_noise(key, image, 3e-3, 0.01)),
        "blur": ("Gaussian blur, sigma 1.2 px", ph.gaussian_blur(image, 1.2, 4)),
        "colour": ("exposure 1.5, gains R 1.15 B 0.85, gamma 0.8",
                   ph.exposure_white_balance(image, 1.5, jnp.array([1.15, 1.0, 0.85]), 0.8)),
        "vignetting": ("vignetting, strength 0.6",
                       ph.vignetting(image, centre, 0.5 * min(h, w), 0.6)),
        "jpeg": ("JPEG quality 25 (below the range)", ph.jpeg_compress(image, 25.0)),
        "body": ("random body outline (mask)", image * (1.0 - body)[..., None]),
    }


def _panel(before: np.ndarray, after: np.ndarray, title: str) -> np.ndarray:
    gap = np.ones((before.shape[0], 6, 3), np.float32)
    row = np.concatenate([before, gap, after], axis=1)
    band = np.ones((22, row.shape[1], 3), np.float32)
    out = np.concatenate([band, row], axis=0)
    bgr = np.round(np.clip(out, 0, 1)[..., ::-1] * 255).astype(np.uint8)
    cv2.putText(bgr, f"before | after: {title}", (4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.38,
                (0, 0, 0), 1, cv2.LINE_AA)
    return bgr


def main() -> None:
    rig = scale_rig(builtin_rig("paper-train"), SCALE)
    sample = render_sample(rig, SEED, noise=False)     # the clean "before"
    image = jnp.asarray(sample["images"][0], jnp.float32) / 255.0
    mask = jnp.asarray(sample["masks"][0], jnp.float32)
    cam = rig.cameras[0]
    centre = (float(cam.cx), float(cam.cy))
    for name, (title, after) in _figures(image, mask, centre).items():
        path = OUT / f"augment_{name}.png"
        cv2.imwrite(str(path), _panel(np.asarray(image), np.asarray(after), title),
                    [cv2.IMWRITE_PNG_COMPRESSION, 9])
        print(f"{path.name}: {path.stat().st_size / 1024:.0f} kB")


if __name__ == "__main__":
    main()
