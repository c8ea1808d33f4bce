"""``gijax render``: options, resume after an interruption, refusal of mismatched settings.

The renderer is replaced by a fast stand-in that derives arrays from the seed, so these tests
exercise the command and the dataset plumbing, not the ray caster (tested on its own).
"""

from __future__ import annotations

import numpy as np
import pytest

import gijax.render
from gijax.cli import main
from gijax.data.reader import DatasetReader
from gijax.data.writer import sample_seed
from gijax.io.rigfile import save_rig
from test_data_format import _tree, tiny_rig


def fake_render(rig, seed, pano, style="mixed"):
    rng = np.random.default_rng(seed)
    n, h, w = rig.num_cameras, rig.cameras[0].height, rig.cameras[0].width
    return {"images": rng.integers(0, 256, (n, h, w, 3), dtype=np.uint8),
            "distances": rng.uniform(0.5, 99.0, (n, h, w)).astype(np.float32),
            "masks": np.stack([np.asarray(m > 0.5, np.uint8) for m in rig.masks]),
            "pano_distance": rng.uniform(0.5, 99.0, pano.shape).astype(np.float32)}


@pytest.fixture(scope="module")
def rig_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("rig") / "tiny.yaml"
    save_rig(tiny_rig(), path)
    return str(path)


def _args(rig_file, out, samples, *extra):
    return ["render", "--rig", rig_file, "--samples", str(samples), "--out", str(out),
            "--seed", "2", "--pano", "32x8", *extra]


def test_render_writes_seeded_samples(rig_file, tmp_path, monkeypatch):
    monkeypatch.setattr(gijax.render, "render_sample", fake_render)
    out = tmp_path / "d"
    assert main(_args(rig_file, out, 3, "--size", "16x16")) == 0
    reader = DatasetReader(out)
    assert len(reader) == 3 and reader.pano.shape == (8, 32)
    assert reader.rig.cameras[0].width == 16
    for i in range(3):
        s = reader[i]
        assert s["seed"] == sample_seed(2, i)
        want = fake_render(reader.rig, s["seed"], reader.pano)
        for k in ("images", "distances", "masks", "pano_distance"):
            np.testing.assert_array_equal(s[k], want[k])
    # Asking for fewer or the same samples changes nothing.
    before = _tree(out)
    assert main(_args(rig_file, out, 2, "--size", "16x16")) == 0
    assert _tree(out) == before


def test_render_interrupted_then_resumed_is_identical(rig_file, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(gijax.render, "render_sample", fake_render)
    ref = tmp_path / "ref"
    assert main(_args(rig_file, ref, 4)) == 0
    calls = []

    def dying(rig, seed, pano, style="mixed"):
        calls.append(seed)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return fake_render(rig, seed, pano, style)

    out = tmp_path / "out"
    monkeypatch.setattr(gijax.render, "render_sample", dying)
    # Ctrl-C: exit status 130 and one line saying what was kept, no traceback.
    assert main(_args(rig_file, out, 4)) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"gijax render: interrupted; {out} keeps the samples written so far; the same command "
        f"continues from them")
    with pytest.raises(ValueError, match=r"incomplete: 2 of the 4 samples"):
        DatasetReader(out)
    assert main(["data", "check", str(out), "--no-progress"]) == 1   # incomplete
    with pytest.warns(UserWarning, match="2 of the 4"):
        assert len(DatasetReader(out, allow_partial=True)) == 2
    monkeypatch.setattr(gijax.render, "render_sample", fake_render)
    assert main(_args(rig_file, out, 4)) == 0
    assert "resuming after 2 complete samples" in capsys.readouterr().out
    assert _tree(out) == _tree(ref)
    assert main(["data", "check", str(out), "--no-progress"]) == 0


def test_render_refuses_other_settings_and_bad_sizes(rig_file, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(gijax.render, "render_sample", fake_render)
    out = tmp_path / "d"
    assert main(_args(rig_file, out, 1)) == 0
    args = _args(rig_file, out, 2)
    args[args.index("--seed") + 1] = "3"
    assert main(args) == 1
    assert "generator settings" in capsys.readouterr().err
    assert main(_args(rig_file, tmp_path / "e", 1, "--size", "16x8")) == 1
    assert "changes the aspect of camera 'cam0'" in capsys.readouterr().err
    assert main(_args("no-such-rig", tmp_path / "f", 1)) == 1
    assert "not a built-in rig name" in capsys.readouterr().err


@pytest.mark.parametrize("extra, message", [
    (("--scale", "0"), "--scale must be a positive number; found 0.0"),
    (("--scale", "-1"), "--scale must be a positive number; found -1.0"),
    (("--scale", "nan"), "--scale must be a positive number; found nan"),
    (("--scale", "2000"), "camera 'cam0': 64000x64000 (width x height) has a side beyond the "
                          "32768-pixel bound"),
    (("--pano", "100000x100000"), "the panorama: 100000x100000 (width x height) has a side "
                                  "beyond the 32768-pixel bound"),
])
def test_render_refuses_sizes_it_cannot_render_before_making_the_folder(
        rig_file, tmp_path, capsys, monkeypatch, extra, message):
    monkeypatch.setattr(gijax.render, "render_sample", fake_render)
    out = tmp_path / "d"
    args = _args(rig_file, out, 1)
    if extra[0] == "--pano":
        args[args.index("--pano") + 1] = extra[1]
    else:
        args += list(extra)
    assert main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    # Nothing is left behind that the corrected command would trip on.
    assert not out.exists()
    assert main(_args(rig_file, out, 1)) == 0


def test_render_refuses_what_does_not_fit_in_memory(rig_file, tmp_path, capsys, monkeypatch):
    from gijax.io import bounds

    monkeypatch.setattr(gijax.render, "render_sample", fake_render)
    monkeypatch.setattr(bounds, "available_memory", lambda: 2**30)
    # Three 32 x 32 cameras at scale 32 are 1024 x 1024: 3 M pixels x 256 B = 0.75 GiB, plus a
    # 2048 x 1024 panorama x 128 B = 0.25 GiB: 1 GiB, more than the 0.5 GiB half.
    args = _args(rig_file, tmp_path / "d", 1, "--scale", "32")
    args[args.index("--pano") + 1] = "2048x1024"
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "cameras 1024x1024, 1024x1024, 1024x1024 and a 2048x1024 panorama (width x height) " \
           "need about 1.0 GiB, more than half of the 1.0 GiB" in err, err
    assert not (tmp_path / "d").exists()
