"""What a model was trained on (its provenance's dataset records) against the rig it is run on:
the ranges, each way a rig lies outside them, and the one warning line of predict."""

import numpy as np

from gijax.geometry.layouts import builtin_rig
from gijax.store.envelope import (TrainingEnvelope, envelope_note,
                                  outside_envelope, rig_spacing, training_envelope)

PROVENANCE = {"data": [
    {"role": "mix-paper-train", "rig": "paper-train", "lens": "own", "cameras": 3,
     "fov_deg": [195.0, 195.0, 195.0]},
    {"role": "mix-layout-0", "rig": "layout-0", "lens": "kb", "cameras": 4,
     "fov_deg": [215.0, 232.9, 190.0, 205.0], "models": ["kb"] * 4, "spacing_m": [0.5, 0.9]},
    {"role": "val", "rig": "paper-train", "lens": "own", "cameras": 3, "fov_deg": [100.0]},
]}


def test_the_envelope_spans_the_training_mixture_only():
    env = training_envelope(PROVENANCE)
    # The validation record is not training data; the paper rig's own lens is equidistant.
    assert env.cameras == (3, 4) and env.fov_deg == (190.0, 232.9)
    assert env.models == frozenset({"equidistant", "kb"})
    assert env.spacing_m is None        # one record lacks it: spacing is not judged
    with_spacing = {"data": [dict(r, spacing_m=[0.31, 0.31]) if r["role"] == "mix-paper-train"
                             else r for r in PROVENANCE["data"]]}
    assert training_envelope(with_spacing).spacing_m == (0.31, 0.9)
    assert training_envelope({}) is None and envelope_note(builtin_rig("paper-train"), {}, "m") \
        is None


def test_each_way_outside_is_named_with_the_trained_range():
    rig = builtin_rig("paper-train")
    np.testing.assert_allclose(rig_spacing(rig), (0.3095, 0.3095), atol=1e-4)
    env = TrainingEnvelope(cameras=(3, 4), fov_deg=(190.0, 232.9), spacing_m=(0.31, 0.9),
                           models=frozenset({"equidistant", "kb"}))
    assert outside_envelope(rig, env) == []
    wide = rig.replace(translations=rig.translations * 4)
    assert outside_envelope(wide, env) == ["camera spacings 1.24-1.24 m (trained on "
                                           "0.31-0.90 m)"]
    # Within the 10 % tolerance: 0.9 m * 1.1 is not exceeded by 0.93 m.
    assert outside_envelope(rig.replace(translations=rig.translations * 3), env) == []
    narrow = TrainingEnvelope(fov_deg=(230.0, 240.0), models=frozenset({"kb"}), cameras=(4, 6))
    assert outside_envelope(rig, narrow) == [
        "3 cameras (trained on 4-6)",
        "fields of view cam0 195, cam1 195, cam2 195 deg (trained on 230-240)",
        "camera model equidistant (trained on kb)"]


def test_predict_warns_in_one_line_on_a_rig_the_bundle_never_saw(tmp_path, capsys):
    import cv2

    from gijax.cli import main
    from gijax.io.rigfile import save_rig

    rig = builtin_rig("paper-train")
    save_rig(rig.replace(translations=rig.translations * 4), tmp_path / "wide.yaml")
    images = []
    for i in range(3):
        images.append(str(tmp_path / f"cam{i}.png"))
        cv2.imwrite(images[-1], np.full((256, 256, 3), 40 * (i + 1), np.uint8))
    rc = main(["predict", "--ckpt", "G16VV-cpu", "--rig", str(tmp_path / "wide.yaml"),
               "--images", *images, "--out", str(tmp_path / "p")])
    err = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert rc == 0
    assert err == ["gijax predict: warning: model 'G16VV-cpu' never saw a rig like this one: "
                   "camera spacings 1.24-1.24 m (trained on 0.31-0.90 m); expect larger errors "
                   "(its PROVENANCE.json says what it was trained on)"], err
