"""Make the files of the "Your own rig" walkthrough (README): a basalt calibration of four
~240-degree Double Sphere fisheyes looking outward around a 7 cm ring, one rig mask per camera
(the mounting pole below the ring) and one rendered image per camera.

The scene is a random gijax scene; the calibration is written as basalt writes it (poses of the
cameras in an IMU frame with +z up), so the import below sees what a real capture would give.

    python docs/examples/four_fisheye_ring/make_example.py [--seed 7] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

SIZE = 256
RADIUS = 0.05          # camera centres 5 cm from the ring's centre: 7 cm between neighbours
INTRINSICS = {"fx": 52.0, "fy": 52.0, "cx": 127.5, "cy": 127.5, "xi": -0.2, "alpha": 0.6}


def ring_poses(n: int = 4):
    """Camera-to-IMU rotations and centres: outward, upright (image down = -z), +z up."""
    rots, centres = [], []
    for k in range(n):
        a = 2 * np.pi * k / n
        fwd = np.array([np.cos(a), np.sin(a), 0.0])
        down = np.array([0.0, 0.0, -1.0])
        right = np.cross(down, fwd)
        rots.append(np.stack([right, down, fwd], 1))
        centres.append(RADIUS * fwd)
    return np.stack(rots), np.stack(centres)


def quaternion(r: np.ndarray) -> list[float]:
    """Hamilton (qx, qy, qz, qw) of a rotation matrix."""
    w = np.sqrt(max(0.0, 1.0 + np.trace(r))) / 2.0
    if w > 1e-6:
        return [(r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w),
                (r[1, 0] - r[0, 1]) / (4 * w), w]
    i = int(np.argmax(np.diag(r)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = np.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k]) * 2.0
    q = [0.0, 0.0, 0.0, 0.0]
    q[i] = s / 4.0
    q[j] = (r[j, i] + r[i, j]) / s
    q[k] = (r[k, i] + r[i, k]) / s
    q[3] = (r[k, j] - r[j, k]) / s
    return q


def main() -> None:
    from gijax.geometry.cameras import make_camera
    from gijax.geometry.occluder import Cylinder
    from gijax.geometry.panorama import Panorama
    from gijax.geometry.rig import make_rig, with_occlusion_masks
    from gijax.render import render_sample

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--out", default=str(Path(__file__).parent))
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    rots, centres = ring_poses()
    calib = {"value0": {
        "T_imu_cam": [dict(zip(("px", "py", "pz"), map(float, c)),
                           **dict(zip(("qx", "qy", "qz", "qw"), map(float, quaternion(r)))))
                      for r, c in zip(rots, centres)],
        "intrinsics": [{"camera_type": "ds", "intrinsics": dict(INTRINSICS)} for _ in rots],
        "resolution": [[SIZE, SIZE] for _ in rots],
    }}
    (out / "calibration.json").write_text(json.dumps(calib, indent=2) + "\n")

    # The mounting pole: a 2 cm-radius cylinder below the ring, in the IMU frame (+z up).
    cam = make_camera("ds", INTRINSICS, SIZE, SIZE)
    pole = Cylinder(*(np.float32(v) for v in (0.0, 0.0, 0.02, -1.5, -0.03)))
    rig = with_occlusion_masks(make_rig([cam] * 4, rots, centres, np.zeros(3), occluder=pole,
                                        names=[f"cam{k}" for k in range(4)]))
    sample = render_sample(rig, args.seed, pano=Panorama.sphere(16, 32), style="indoor")
    for k in range(4):
        cv2.imwrite(str(out / f"cam{k}.png"),
                    np.ascontiguousarray(np.asarray(sample["images"][k])[..., ::-1]))
        cv2.imwrite(str(out / f"mask_cam{k}.png"),
                    (np.asarray(rig.masks[k]) > 0.5).astype(np.uint8) * 255)
    print(f"wrote {out}/calibration.json, cam0..3.png, mask_cam0..3.png")


if __name__ == "__main__":
    main()
