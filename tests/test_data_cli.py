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
