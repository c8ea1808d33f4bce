"""``gijax predict --method rtss``: the classical baseline from image files, no model needed."""

import cv2
import numpy as np

from gijax.cli import main
from gijax.geometry.layouts import builtin_rig
from gijax.geometry.panorama import Panorama
from gijax.geometry.rig import scale_rig
from gijax.render import render_fronto_plane


def test_rtss_predict_from_files_recovers_a_known_distance(tmp_path, capsys):
    # A textured sphere 2.2 m around the reference point of the training rig, rendered at
    # 1/8 of the calibrated size: the images are smaller than the rig file says, so the
    # command must rescale the lens (same aspect) before matching.
    rig = scale_rig(builtin_rig("paper-train"), 0.125)
    sample = render_fronto_plane(rig, 2.2, seed=4, pano=Panorama.hemisphere(16, 64))
    paths = []
    for i, im in enumerate(sample["images"]):
        paths.append(str(tmp_path / f"cam{i}.png"))
        cv2.imwrite(paths[-1], np.ascontiguousarray(im[..., ::-1]))
    out = tmp_path / "out"
    code = main(["predict", "--method", "rtss", "--rtss-preset", "RS-E16", "--rig", "paper-train",
                 "--images", *paths, "--out", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "classical baseline RS-E16" in text
    # The size policy's note, and the default candidate list named with its count.
    assert "images are 128 x 128; the rig's 1024 x 1024 lenses are rescaled by 0.125" in text
    assert "RS-E16's own list (16 even in inverse distance, 0.5-100 m); 16 from 0.500" in text
    assert "over valid pixels" in text
    # No uncertainty map (the baseline has no candidate distribution); a colour panorama.
    assert not (out / "uncertainty.png").exists()
    rgb = cv2.imread(str(out / "rgb.png"))
    assert rgb.shape == (160, 640, 3) and rgb.std() > 5
    distance = np.load(out / "distance.npy")
    meta = (out / "prediction.json").read_text()
    assert distance.shape == (160, 640) and "candidates_m" in meta
    finite = np.isfinite(distance)
    assert finite.mean() > 0.5
    # Inverse-distance error of the median against the truth, far below one EV step (0.13 1/m).
    assert abs(1.0 / np.median(distance[finite]) - 1.0 / 2.2) < 0.05
    assert (out / "points.ply").stat().st_size > 1000


def test_learned_method_needs_a_model(tmp_path, capsys):
    img = tmp_path / "a.png"
    cv2.imwrite(str(img), np.zeros((8, 8, 3), np.uint8))
    code = main(["predict", "--rig", "paper-train", "--images", str(img), str(img), str(img),
                 "--out", str(tmp_path / "o")])
    assert code == 1
    assert "--ckpt" in capsys.readouterr().err
