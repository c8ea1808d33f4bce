"""Candidate specs (gijax.candidates.spec): files in every accepted format, the 'train'
fallbacks against the released lists, and the checks every command relies on."""

import numpy as np
import pytest

from gijax.candidates.spec import read_candidate_file, resolve_candidates
from gijax.geometry.layouts import builtin_rig

# The released G8 list (REFERENCE section 2): GI, closed form at b = 0.3095 m.
G8 = [0.5, 0.60103325, 0.73863074, 0.94007016, 1.26849604, 1.91086214, 3.77357055, 100.0]


@pytest.fixture(scope="module")
def rig():
    return builtin_rig("paper-train")


def test_candidate_files_in_every_format(tmp_path):
    want = [0.5, 1.0, 2.5, 100.0]
    texts = {"list.json": "[0.5, 1.0, 2.5, 100.0]",
             "object.json": '{"candidates": [0.5, 1.0, 2.5, 100.0], "note": "x"}',
             "lines.txt": "0.5\n1.0\n2.5\n100.0\n",
             "commas.txt": "0.5, 1.0,2.5 ,100.0"}
    for name, text in texts.items():
        (tmp_path / name).write_text(text)
        got = read_candidate_file(tmp_path / name)
        assert got.dtype == np.float64
        np.testing.assert_array_equal(got, want)
    for name, text, msg in (("bad.txt", "0.5 one 2", "one number per line"),
                            ("empty.json", "[]", "non-empty list"),
                            ("dict.json", '{"other": 1}', "non-empty list")):
        (tmp_path / name).write_text(text)
        with pytest.raises(ValueError, match=msg):
            read_candidate_file(tmp_path / name)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        read_candidate_file(tmp_path / "missing.json")


def test_train_spec_uses_the_training_list_or_the_kind_in_closed_form(rig):
    trained = np.geomspace(0.5, 100.0, 8)
    got, label = resolve_candidates("train", rig, 8, train=trained)
    np.testing.assert_array_equal(got, trained)
    assert label == "training list"
    # Without a training list (an untrained preset): the released G8, or EV written out.
    got, label = resolve_candidates("train", rig, 8, kind="gi")
    np.testing.assert_allclose(got, G8, rtol=1e-6)
    assert label == "GI closed form"
    got, label = resolve_candidates("train", rig, 8, kind="ev")
    np.testing.assert_allclose(got, 1.0 / np.linspace(2.0, 0.01, 8), rtol=1e-6)
    assert label == "EV closed form"
    with pytest.raises(ValueError, match="no training list"):
        resolve_candidates("train", rig, 8)


def test_recomputed_spec_on_the_training_rig_is_the_released_list(rig):
    # The training triangle's spacing is the released lists' baseline.
    got, label = resolve_candidates("spacing", rig, 8, train=np.ones(8))
    np.testing.assert_allclose(got, G8, rtol=1e-5)
    assert "camera spacing" in label


def test_file_spec_count_and_order_are_checked(tmp_path, rig):
    short = tmp_path / "short.json"
    short.write_text("[0.5, 1.0, 100.0]")
    with pytest.raises(ValueError, match="must hold 8 distances; found 3"):
        resolve_candidates(str(short), rig, 8)
    # A method without a fixed count (the classical baseline) takes it as it is.
    got, label = resolve_candidates(str(short), rig, 8, any_count=True)
    np.testing.assert_array_equal(got, [0.5, 1.0, 100.0])
    assert label == f"from {short}"
    unordered = tmp_path / "unordered.json"
    unordered.write_text("[0.5, 2.0, 1.0]")
    with pytest.raises(ValueError, match="ascending"):
        resolve_candidates(str(unordered), rig, 3)


def test_train_takes_the_same_specs(tmp_path, capsys):
    # 'gijax train --candidates': a file as before, and the keywords (EV needs no rig).
    from gijax.cli import build_parser
    from gijax.cli.cmd_train import _training_list
    from gijax.train.config import TrainConfig

    cfg = TrainConfig(preset="G16VV-cpu")
    mc = cfg.model_config()

    def listed(spec):
        args = build_parser().parse_args(["train", "--preset", "G16VV-cpu", "--data", "d",
                                          "--out", "o", "--candidates", spec])
        return _training_list(args, cfg)

    assert listed("train") is None              # the preset's own kind, chosen by the trainer
    want = 1.0 / np.linspace(1.0 / mc.d_min, 1.0 / mc.d_max, mc.num_candidates)
    np.testing.assert_allclose(listed("ev"), want, rtol=2e-6)     # computed in float32
    (tmp_path / "list.txt").write_text(" ".join(str(v) for v in want[::-1] * 0 + want))
    np.testing.assert_allclose(listed(str(tmp_path / "list.txt")), want, rtol=1e-12)
    with pytest.raises(FileNotFoundError, match="not one of the keywords train, spacing, rig"):
        listed("spcing")
