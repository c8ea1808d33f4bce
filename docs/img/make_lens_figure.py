"""Draw docs/img/lens_draws.png: one scene seen by camera 0 of ``paper-train`` through its own
lens and through three drawn ones (``gijax render --lens``), with the rendered validity masks.

Run from the repository root:

    python docs/img/make_lens_figure.py
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import jax
import numpy as np

from gijax.data.lens_draw import LensDraw, draw_lens
from gijax.geometry.layouts import builtin_rig
from gijax.geometry.rig import scale_rig, with_occlusion_masks
from gijax.render import render_scene, sample_scene

OUT = Path(__file__).resolve().parent
SCALE = 0.1875        # 1024 px synthetic fisheyes -> 192 px
SEED = 7
DRAWS = (("equidistant", 180.0), ("kb", 210.0), ("ds", 240.0))


def _panel(image: np.ndarray, mask: np.ndarray, title: str) -> np.ndarray:
    shown = image.astype(np.float32) / 255.0 * (0.35 + 0.65 * mask[..., None])
    band = np.ones((22, shown.shape[1], 3), np.float32)
    out = np.concatenate([band, shown], axis=0)
    bgr = np.round(np.clip(out, 0, 1)[..., ::-1] * 255).astype(np.uint8)
    cv2.putText(bgr, title, (4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
    return bgr


def main() -> None:
    rig = scale_rig(builtin_rig("paper-train"), SCALE)
    scene = sample_scene(rig, SEED)
    panels = []
    cam = rig.cameras[0]
    variants = [("paper-train lens", rig)]
    for i, (model, fov) in enumerate(DRAWS):
        lens = draw_lens(jax.random.PRNGKey(i), cam, model, LensDraw(fov_deg=(fov, fov)))
        variants.append((f"{model}, {fov:.0f} deg", with_occlusion_masks(
            rig.replace(cameras=(lens,) + rig.cameras[1:]))))
    for title, r in variants:
        out = render_scene(r, scene, SEED, noise=False)
        fov = math.degrees(float(r.cameras[0].fov))
        label = title if "deg" in title else f"{title} ({fov:.0f} deg)"
        panels.append(_panel(out["images"][0], np.asarray(out["masks"][0], np.float32), label))
    gap = np.full((panels[0].shape[0], 6, 3), 255, np.uint8)
    row = panels[0]
    for p in panels[1:]:
        row = np.concatenate([row, gap, p], axis=1)
    cv2.imwrite(str(OUT / "lens_draws.png"), row)
    print(f"wrote {OUT / 'lens_draws.png'}")


if __name__ == "__main__":
    main()
