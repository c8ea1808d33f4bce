"""The bundled model's recipe (experiments/bundle_model.py): its mixture, seeds and target
checks. The script end to end was run at the smoke scale by hand (about 3 min on 2 cores,
nearly all XLA compilation); these are its parts that decide what the bundle is judged by."""

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments import bundle_model as B  # noqa: E402
from experiments import learned_candidates, scales  # noqa: E402


def test_random_layouts_are_planar_3_or_4_cameras_25_to_80_cm_apart():
    """Neighbouring cameras (around the polygon) lie 0.25 x 0.9 .. 0.8 x 1.1 m apart (the side
    drawn in 0.25-0.8 m, each radius jittered by 10 %), all in the z = 0 plane facing up, the
    reference at the centroid or on camera 0; the draw is fixed by k."""
    counts, refs = set(), set()
    for k in range(12):
        rig = B.random_layout(k)
        pos = np.asarray(rig.translations, np.float64)
        n = len(pos)
        counts.add(n)
        assert n in (3, 4) and np.allclose(pos[:, 2], 0.0)
        order = np.argsort(np.arctan2(pos[:, 1] - pos[:, 1].mean(), pos[:, 0] - pos[:, 0].mean()))
        ring = pos[order]
        gaps = np.linalg.norm(ring - np.roll(ring, 1, axis=0), axis=1)
        assert gaps.min() > 0.25 * 0.8 and gaps.max() < 0.8 * 1.25, gaps
        np.testing.assert_allclose(np.asarray(rig.rotations), np.tile(np.eye(3), (n, 1, 1)))
        ref = np.asarray(rig.reference, np.float64)
        refs.add("centroid" if np.allclose(ref, pos.mean(0), atol=1e-6) else
                 "camera 0" if np.allclose(ref, pos[0], atol=1e-6) else "other")
        np.testing.assert_array_equal(B.random_layout(k).translations, rig.translations)
    assert counts == {3, 4} and refs == {"centroid", "camera 0"}


def test_mixture_seeds_are_its_own():
    """Every mixture dataset has its own scene seed and lens seed, none used by the tables'
    data (training, validation, tests) or the learned-candidates data."""
    roles = B.mixture_roles(B.RECIPES["cpu"])
    assert len(roles) == 1 + 3 + 4 and roles[0] == ("mix-paper-train", "paper-train", None)
    scene_seeds = [B.MIX_SEED + i for i in range(len(roles))]
    taken = set(scales.DATA_SEEDS.values()) | set(learned_candidates.SEEDS.values())
    assert not taken & set(scene_seeds)
    lens = [s for _, _, s in roles if s is not None]
    assert len(set(lens)) == len(lens) == 7
    assert all(r.startswith("layout-") for _, r, s in roles[4:])


def test_a_second_round_of_the_mixture_draws_new_scenes_lenses_and_layouts():
    """``rounds=2`` keeps the first round's datasets as they are (names, rigs, lens seeds and,
    by their place, scene seeds) and adds as many again with new ones: new scene seeds, lens
    seeds and random layouts, none shared with the tables' data."""
    one = B.mixture_roles(B.RECIPES["cpu"])
    two = B.mixture_roles(B.MORE_RECIPES["cpu"])
    assert B.MORE_RECIPES["cpu"].rounds == 2 and len(two) == 2 * len(one)
    assert two[:len(one)] == one
    second = two[len(one):]
    assert second[0] == ("mix-paper-train-r1", "paper-train", None)
    assert len({r for r, _, _ in two}) == len(two)                # every folder its own
    lens = [s for _, _, s in two if s is not None]
    assert len(set(lens)) == len(lens) == 14
    layouts = [b for _, b, _ in second if b.startswith("layout-")]
    assert layouts == [f"layout-{k}" for k in range(4, 8)]
    positions = [np.asarray(B.random_layout(k).translations) for k in range(8)]
    for new in positions[4:]:
        assert not any(old.shape == new.shape and np.allclose(old, new)
                       for old in positions[:4])
    taken = set(scales.DATA_SEEDS.values()) | set(learned_candidates.SEEDS.values())
    assert not taken & {B.MIX_SEED + i for i in range(len(two))}


def test_the_more_recipe_fine_tunes_the_fine_bundle_on_two_rounds_read_by_the_mode(tmp_path):
    """``--recipe more``: the fine bundle's configuration with the mode estimate, started from
    it at the cpu scale, with its own run and pack folders and all 16 folders as data."""
    from gijax.store import load_model

    cpu = scales.SCALES["cpu"]
    design = "G16VV-cpu-zncc"
    plan = B.Plan("more", design, B.pack_folder(cpu, design, tmp_path, "more"))
    assert plan.pack == Path(B.__file__).resolve().parent / "packs" / f"more-{design}"
    recipe = plan.recipe(cpu)
    assert recipe.init_from == f"{design}-fine"
    cfg = B.train_config(cpu, recipe, 0, plan)
    _, fine, _ = load_model(recipe.init_from)
    assert cfg.model_config() == dataclasses.replace(fine, estimate="mode")
    data = [{"role": r, "path": str(tmp_path / "data" / r)}
            for r, _, _ in B.mixture_roles(recipe)]
    argv = [str(a) for a in B.train_argv(tmp_path, cpu, recipe, 0, data, plan)]
    assert argv[argv.index("--out") + 1] == str(tmp_path / "runs" / f"more-{design}")
    folders = argv[argv.index("--data") + 1:argv.index("--val")]
    assert len(folders) == 16 and folders[8] == str(tmp_path / "data" / "mix-paper-train-r1")


@pytest.mark.parametrize("kind, before", [("third", "more"), ("fourth", "third")])
def test_a_new_draw_continues_the_previous_draws_pack_on_one_more_round(tmp_path, kind, before):
    """``--recipe third`` / ``fourth``: starts from the previous kind's committed pack (a model
    that ``--init-from`` reads: the same network as the run's, the fine bundle's read by the
    mode), is compared with it, trains on every folder of the previous draws plus 8 new ones
    whose scene seeds and lens seeds are new, in its own run and pack folders."""
    from gijax.store import load_model

    cpu, smoke = scales.SCALES["cpu"], scales.SCALES["smoke"]
    design = "G16VV-cpu-zncc"
    plan = B.Plan(kind, design, B.pack_folder(cpu, design, tmp_path, kind), tmp_path)
    packs = Path(B.__file__).resolve().parent / "packs"
    assert plan.pack == packs / f"{kind}-{design}"
    recipe = plan.recipe(cpu)
    earlier = B.KINDS[before].recipes["cpu"]
    rounds = earlier.rounds + 1
    assert recipe.rounds == rounds and recipe.init_from == str(packs / f"{before}-{design}")
    assert B.KINDS[kind].previous(cpu, design, tmp_path) == recipe.init_from
    cfg = B.train_config(cpu, recipe, 0, plan)
    _, start, cand = load_model(recipe.init_from)
    _, fine, fine_cand = load_model(f"{design}-fine")
    assert cfg.model_config() == start == dataclasses.replace(fine, estimate="mode")
    np.testing.assert_allclose(cand, fine_cand, rtol=1e-6)
    roles = B.mixture_roles(recipe)
    previous = B.mixture_roles(earlier)
    assert len(roles) == 8 * rounds and roles[:8 * (rounds - 1)] == previous
    assert roles[8 * (rounds - 1)] == (f"mix-paper-train-r{rounds - 1}", "paper-train", None)
    lens = [s for _, _, s in roles if s is not None]
    assert len(set(lens)) == len(lens) == 7 * rounds
    taken = set(scales.DATA_SEEDS.values()) | set(learned_candidates.SEEDS.values())
    assert not taken & {B.MIX_SEED + i for i in range(len(roles))}
    data = [{"role": r, "path": str(tmp_path / "data" / r)} for r, _, _ in roles]
    argv = [str(a) for a in B.train_argv(tmp_path, cpu, recipe, 0, data, plan)]
    assert argv[argv.index("--out") + 1] == str(tmp_path / "runs" / f"{kind}-{design}")
    assert argv[argv.index("--init-from") + 1] == str(packs / f"{before}-{design}")
    assert len(argv[argv.index("--data") + 1:argv.index("--val")]) == 8 * rounds
    # At the smoke scale: random weights, as every recipe's pipeline check.
    assert B.Plan(kind, design, tmp_path / "p", tmp_path).recipe(smoke).init_from is None


def test_the_dense_kind_reads_the_fourth_draws_network_at_twice_its_candidates(tmp_path):
    """``--recipe dense``: the fourth draw's committed pack, at 32 candidates where it has 16
    (the count is no weight's size: the pack's variables initialise the run's network), on the
    fourth draw's mixture, compared with that pack; its command overrides the count."""
    from flax import nnx

    from gijax.model import OmniStereoNet
    from gijax.store import load_model
    from gijax.train.run_folder import initial_variables

    cpu = scales.SCALES["cpu"]
    design = "G16VV-cpu-zncc"
    plan = B.Plan("dense", design, B.pack_folder(cpu, design, tmp_path, "dense"), tmp_path)
    packs = Path(B.__file__).resolve().parent / "packs"
    recipe = plan.recipe(cpu)
    assert recipe.init_from == str(packs / f"fourth-{design}")
    assert B.KINDS["dense"].previous(cpu, design, tmp_path) == recipe.init_from
    assert B.mixture_roles(recipe) == B.mixture_roles(B.KINDS["fourth"].recipes["cpu"])
    cfg = B.train_config(cpu, recipe, 0, plan)
    _, start, _ = load_model(recipe.init_from)
    assert start.num_candidates == 16
    mc = cfg.model_config()
    assert mc == dataclasses.replace(start, num_candidates=32)
    data = [{"role": r, "path": str(tmp_path / "data" / r)} for r, _, _ in B.mixture_roles(recipe)]
    argv = [str(a) for a in B.train_argv(tmp_path, cpu, recipe, 0, data, plan)]
    assert "num_candidates=32" in argv
    # The pack's weights become the 32-candidate network's, every variable of the same shape.
    model = nnx.eval_shape(lambda: OmniStereoNet(mc, nnx.Rngs(0)))
    _, params, rest = nnx.split(model, nnx.Param, ...)
    got, _ = initial_variables(cfg, mc, params, rest)
    start_net, _, _ = load_model(recipe.init_from)
    want = nnx.to_pure_dict(nnx.split(start_net, nnx.Param, ...)[1])
    flat_got = dict(nnx.traversals.flatten_mapping(nnx.to_pure_dict(got)))
    flat_want = dict(nnx.traversals.flatten_mapping(want))
    assert flat_got.keys() == flat_want.keys()
    for k in flat_want:
        np.testing.assert_array_equal(np.asarray(flat_got[k]), np.asarray(flat_want[k]))


def _row(test, model, lst, mae):
    return {"test": test, "model": model, "list": lst, "mae": mae}


def test_run_pieces_follow_the_recorded_starts_and_resumes():
    """Each started / resumed record opens a piece that ends where the next one resumed (its
    later steps were logged again by that one); the last ends at the last logged step. A run
    whose first piece predates the records gets an unrecorded piece from step 0."""
    def steps(a, b):
        return [{"step": s, "loss": 0.1} for s in range(a, b + 1)]

    def event(kind, step, commit):
        return {"step": step, "event": kind, "command": "gijax train --steps 9",
                "git": {"commit": commit, "dirty": False}, "time": f"t{step}"}

    recs = steps(1, 4) + [event("resumed", 4, "aaa")] + steps(5, 7) + [
        {"step": 6, "split": "val", "mae": 0.5}, event("resumed", 6, "bbb")] + steps(7, 9)
    pieces = B.run_pieces(recs)
    assert [(p["event"], p["from_step"], p["to_step"]) for p in pieces] == [
        ("started", 0, 4), ("resumed", 4, 6), ("resumed", 6, 9)]
    assert pieces[0]["recorded"] is False and "command" not in pieces[0]
    assert [p["git"]["commit"] for p in pieces[1:]] == ["aaa", "bbb"]
    assert pieces[2]["command"] == "gijax train --steps 9" and pieces[2]["time"] == "t6"
    whole = B.run_pieces([event("started", 0, "ccc")] + steps(1, 3))
    assert [(p["from_step"], p["to_step"], p["git"]["commit"]) for p in whole] == [(0, 3, "ccc")]
    assert "recorded" not in whole[0]


def test_targets_are_checked_as_stated():
    """paper-test1: <= 0.75 x RS-E32 with the training list; paper-test2/3: the spacing list
    below RS-E32; the ring: the spacing list below RS-E32 and below the training list."""
    m = "new bundle"
    rows = [_row("paper-test1", "RS-E32", "ev", 0.04), _row("paper-test1", m, "train", 0.030),
            _row("paper-test1", m, "spacing", 0.5),
            _row("paper-test2", "RS-E32", "ev", 0.05), _row("paper-test2", m, "train", 0.01),
            _row("paper-test2", m, "spacing", 0.051),
            _row("paper-test3", "RS-E32", "ev", 0.05), _row("paper-test3", m, "train", 0.9),
            _row("paper-test3", m, "spacing", 0.049),
            _row(B.RING, "RS-E32", "ev", 0.05), _row(B.RING, m, "train", 0.045),
            _row(B.RING, m, "spacing", 0.046)]
    got = {t["test"]: t for t in B.check_targets(rows, m)}
    assert got["paper-test1"]["status"] == "MET"                       # 0.030 <= 0.75 x 0.04
    assert got["paper-test1"]["numbers"]["ratio"] == pytest.approx(0.75)
    assert got["paper-test2"]["status"] == "MISSED"                    # spacing 0.051 > 0.05
    assert got["paper-test3"]["status"] == "MET"                       # 0.049 < 0.05
    assert got[B.RING]["status"] == "MISSED"                           # 0.046 > train 0.045
    rows[1]["mae"] = 0.0301
    rows[-1]["mae"] = 0.044
    got = {t["test"]: t for t in B.check_targets(rows, m)}
    assert got["paper-test1"]["status"] == "MISSED" and got[B.RING]["status"] == "MET"


def test_training_command_names_every_mixture_folder_and_the_recipe(tmp_path):
    """The recorded command is the 'gijax train' call: every mixture folder after --data, the
    augmentation, calibration error and schedule of the recipe."""
    scale, recipe = scales.SCALES["cpu"], B.RECIPES["cpu"]
    data = [{"role": r, "path": str(tmp_path / "data" / r)}
            for r, _, _ in B.mixture_roles(recipe)] + [{"role": "val", "path": "v"}]
    argv = [str(a) for a in B.train_argv(tmp_path, scale, recipe, 0, data)]
    i = argv.index("--data")
    assert argv[i + 1:i + 9] == [d["path"] for d in data[:8]] and argv[i + 9] == "--val"
    for flag, value in (("--augment", "photometric+body"), ("--calibration-error", "0.5"),
                        ("--schedule", "warmup_cosine"), ("--steps", "600"),
                        ("--batch", "8"), ("--init-from", "G16VV-cpu")):
        assert argv[argv.index(flag) + 1] == value


def test_the_long_recipe_trains_its_design_from_random_weights_with_a_committed_pack(tmp_path):
    """``--recipe long``: the design's own preset (smoke overrides at the smoke scale), random
    weights, the pack folder under experiments/packs/ at the cpu scale (committed) and beside
    the output elsewhere, and the pack in the recorded command so that the command resumes."""
    plan = B.Plan("long", "G16VV-cpu-zncc", B.pack_folder(scales.SCALES["cpu"],
                                                               "G16VV-cpu-zncc", tmp_path))
    assert plan.pack == Path(B.__file__).resolve().parent / "packs" / "long-G16VV-cpu-zncc"
    recipe = B.LONG_RECIPES["cpu"]
    cfg = B.train_config(scales.SCALES["cpu"], recipe, 0, plan)
    assert cfg.preset == "G16VV-cpu-zncc" and cfg.model_overrides == {}
    assert cfg.init_from is None and cfg.steps == recipe.steps and cfg.pack == str(plan.pack)
    argv = [str(a) for a in B.train_argv(tmp_path, scales.SCALES["cpu"], recipe, 0, [], plan)]
    assert argv[argv.index("--pack") + 1] == str(plan.pack)
    assert argv[argv.index("--out") + 1] == str(tmp_path / "runs" / "long-G16VV-cpu-zncc")
    smoke = B.train_config(scales.SCALES["smoke"], B.LONG_RECIPES["smoke"], 0,
                           B.Plan("long", "G16VV-cpu-fine", None))
    # The fine design keeps its cost volume at the output's size when shrunk.
    assert smoke.model_overrides["cost_hw"] == smoke.model_overrides["output_hw"]
    assert B.pack_folder(scales.SCALES["smoke"], "x", tmp_path) == tmp_path / "packs" / "long-x"
    # The fine-tuning recipe is unchanged: the bundle's preset from the bundle, no pack.
    fine = B.train_config(scales.SCALES["cpu"], B.RECIPES["cpu"], 0)
    assert fine.preset == "G16VV-cpu" and fine.init_from == "G16VV-cpu" and fine.pack is None


def test_the_bundled_step_is_the_checkpoint_the_bundle_takes(tmp_path):
    """The bundle takes the newest checkpoint of the run's best folder, else the newest periodic
    one; a folder restored from a pack holds no best checkpoint of the validations before it,
    so the provenance must name the step it actually holds."""
    run = tmp_path / "run"
    assert B.bundled_step(run) is None
    for step in (8250, 8500, 9000):
        (run / "checkpoints" / str(step)).mkdir(parents=True)
    (run / "checkpoints" / "tmp-9250").mkdir()            # an unfinished save: not a step
    assert B.bundled_step(run) == 9000
    (run / "best" / "9000").mkdir(parents=True)
    (run / "checkpoints" / "9250").mkdir()
    assert B.bundled_step(run) == 9000


def test_the_cells_recipe_fine_tunes_the_designs_bundle_at_one_cell_per_output_pixel(tmp_path):
    """``--recipe cells``: the design's preset with the cost volume at the output's size
    (``cost_hw`` = ``output_hw``, stride 1; at the smoke scale on the shrunk network), started
    from the design's bundle at the cpu scale (random weights at the smoke scale, which has no
    bundle), its own run and committed pack folders, and the recorded command carrying all of it
    so that the same command resumes."""
    from gijax.nn.presets import get_preset

    cpu, smoke = scales.SCALES["cpu"], scales.SCALES["smoke"]
    design = "G16VV-cpu-zncc"
    plan = B.Plan("cells", design, B.pack_folder(cpu, design, tmp_path, "cells"))
    assert plan.pack == Path(B.__file__).resolve().parent / "packs" / f"cells-{design}"
    recipe = plan.recipe(cpu)
    assert recipe.init_from == design and recipe.steps == 6000 and recipe.lr == 1e-4
    cfg = B.train_config(cpu, recipe, 0, plan)
    base = get_preset(design)
    assert base.cost_hw == (16, 64) and base.output_stride == 2      # the design: 2 x 2 cells
    assert cfg.preset == design
    assert cfg.model_overrides == {"cost_hw": [32, 128], "output_stride": 1}
    mc = cfg.model_config()
    assert tuple(mc.cost_hw) == tuple(mc.output_hw) == (32, 128)
    argv = [str(a) for a in B.train_argv(tmp_path, cpu, recipe, 0, [], plan)]
    assert argv[argv.index("--out") + 1] == str(tmp_path / "runs" / f"cells-{design}")
    assert argv[argv.index("--pack") + 1] == str(plan.pack)
    assert argv[argv.index("--init-from") + 1] == design
    overrides = [argv[i + 1] for i, a in enumerate(argv) if a == "--override"]
    assert overrides == ["cost_hw=[32,128]", "output_stride=1"]
    for flag, value in (("--steps", "6000"), ("--batch", "8"), ("--lr", "0.0001"),
                        ("--warmup-steps", "200"), ("--ckpt-every", "100"),
                        ("--val-every", "250")):
        assert argv[argv.index(flag) + 1] == value
    tiny_plan = B.Plan("cells", design, B.pack_folder(smoke, design, tmp_path, "cells"))
    assert tiny_plan.pack == tmp_path / "packs" / f"cells-{design}"
    tiny = tiny_plan.recipe(smoke)
    assert tiny.init_from is None
    small = B.train_config(smoke, tiny, 0, tiny_plan).model_config()
    assert tuple(small.cost_hw) == tuple(small.output_hw) and small.output_stride == 1
    assert small.unet_base < base.unet_base                          # the smoke shrinking


def test_the_skip_recipe_grows_the_fine_bundle_a_matching_skip_and_reads_it_by_the_mode(
        tmp_path):
    """``--recipe skip``: the fine-cell overrides plus ``matching_skip`` and the mode estimate,
    started from the design's fine bundle at the cpu scale (random weights at the smoke
    scale), its own run and committed pack folders, the recorded command carrying all of it;
    the configuration it builds is the fine bundle's with the skip (what init_from accepts)."""
    from gijax.store import load_model

    cpu, smoke = scales.SCALES["cpu"], scales.SCALES["smoke"]
    design = "G16VV-cpu-zncc"
    plan = B.Plan("skip", design, B.pack_folder(cpu, design, tmp_path, "skip"))
    assert plan.pack == Path(B.__file__).resolve().parent / "packs" / f"skip-{design}"
    recipe = plan.recipe(cpu)
    assert recipe.init_from == f"{design}-fine" and recipe.steps == 1000 and recipe.lr == 3e-5
    cfg = B.train_config(cpu, recipe, 0, plan)
    assert cfg.model_overrides == {"cost_hw": [32, 128], "output_stride": 1,
                                   "matching_skip": True, "estimate": "mode"}
    _, fine, _ = load_model(recipe.init_from)
    assert cfg.model_config() == dataclasses.replace(fine, matching_skip=True)
    argv = [str(a) for a in B.train_argv(tmp_path, cpu, recipe, 0, [], plan)]
    assert argv[argv.index("--out") + 1] == str(tmp_path / "runs" / f"skip-{design}")
    assert argv[argv.index("--init-from") + 1] == f"{design}-fine"
    overrides = [argv[i + 1] for i, a in enumerate(argv) if a == "--override"]
    assert overrides == ["cost_hw=[32,128]", "output_stride=1", "matching_skip=true",
                         'estimate="mode"']
    tiny_plan = B.Plan("skip", design, B.pack_folder(smoke, design, tmp_path, "skip"))
    assert tiny_plan.recipe(smoke).init_from is None
    assert B.train_config(smoke, tiny_plan.recipe(smoke), 0, tiny_plan).model_config().matching_skip


def test_a_run_resuming_from_its_pack_on_a_new_machine_keeps_its_start_record(tmp_path):
    """The start record (initial weights, revision) of a run trained in pieces lives in its
    committed pack, so a milestone bundle published mid-run (which replaces the weights the run
    started from) cannot change it. A pack from before the record lived there takes the
    revision from the pack's first ``started`` log record (not today's) and the weights' hash
    from the record beside the run folder when the machine still has it, and keeps the record
    in the pack from then on. A run without a pack records today's beside its run folder."""
    import json

    from experiments.evaluation import weights_id
    from experiments.provenance import revision
    from gijax.store import resolve_model_path

    cpu, design = scales.SCALES["cpu"], "G16VV-cpu-zncc"
    pack = tmp_path / "pack"
    pack.mkdir()
    (pack / "pack.json").write_text("{}")
    started = {"step": 0, "event": "started", "git": {"commit": "0123abc" * 5 + "01234",
                                                     "dirty": True}}
    (pack / "metrics.jsonl").write_text(json.dumps({"step": 0, "event": "note"}) + "\n"
                                        + json.dumps(started) + "\n"
                                        + json.dumps({"step": 1, "loss": 0.1}) + "\n")
    recipe = B.Plan("cells", design, pack).recipe(cpu)
    run = tmp_path / "runs" / f"cells-{design}"
    bundle_id = weights_id(resolve_model_path(design))
    record = B.initial_weights(run, recipe, pack)
    assert record["git_revision"] == started["git"]["commit"] + "+dirty"
    assert record["weights_sha256_12"] == bundle_id and record["model"] == design
    saved = pack / B.INIT_FILE
    assert json.loads(saved.read_text()) == record
    (pack / "metrics.jsonl").write_text("")           # the record, once written, is kept
    assert B.initial_weights(run, recipe, pack) == record
    # A machine that still has the record beside its run folder keeps that weights' hash
    # (today's bundle may be a milestone published since the run started).
    saved.unlink()
    (pack / "metrics.jsonl").write_text(json.dumps(started) + "\n")
    run.parent.mkdir(parents=True)
    run.with_name(run.name + ".init.json").write_text(json.dumps(
        {"model": design, "weights_sha256_12": "feedc0ffee00", "git_revision": "x"}))
    older = B.initial_weights(run, recipe, pack)
    assert older["weights_sha256_12"] == "feedc0ffee00"
    assert older["git_revision"] == started["git"]["commit"] + "+dirty"
    fresh = B.initial_weights(tmp_path / "runs" / "other", recipe, None)
    assert fresh["git_revision"] == revision() and fresh["weights_sha256_12"] == bundle_id
    assert (tmp_path / "runs" / "other.init.json").is_file()


def test_cached_evaluations_follow_the_model_its_weights_and_how_they_are_read(tmp_path):
    """The evaluation cache's key (``model_id``) follows the weights and the network
    configuration, not the path: the same bundle copied elsewhere keeps its key; read by the
    other estimate (mean or sub-pixel mode) it is another model (same ``weights_id``, another
    ``model_id``), so a result cached for one estimate is never served for the other."""
    import json
    import shutil

    from experiments.evaluation import model_id, weights_id
    from gijax.store import resolve_model_path

    source = resolve_model_path("G16VV-cpu-zncc-fine")
    copies = {}
    for name in ("a", "b", "c"):
        copies[name] = tmp_path / name
        copies[name].mkdir()
        for f in ("weights.npz", "config.json"):
            shutil.copy(source / f, copies[name] / f)
    config = json.loads((copies["c"] / "config.json").read_text())
    own = config["model"].get("estimate", "mean")
    config["model"]["estimate"] = "mode" if own == "mean" else "mean"
    (copies["c"] / "config.json").write_text(json.dumps(config))
    assert model_id(copies["a"]) == model_id(copies["b"]) == model_id(source)
    assert weights_id(copies["c"]) == weights_id(copies["a"])
    assert model_id(copies["c"]) != model_id(copies["a"])


def test_a_bundle_read_by_another_estimate_is_evaluated_under_its_own_key(tmp_path, monkeypatch):
    """``--estimate`` / ``--mode-pick``: the new bundle's evaluations are cached under a key
    naming its reading (and the model's hash), the previous bundle's and RS-E32's under their
    usual keys, and the predictor the key stands for reads the model so."""
    from gijax.store import resolve_model_path

    calls = []

    def fake_cached(work, key, make, data):
        calls.append((key, make))
        return {"mae": 0.01, "first_prediction": np.zeros((2, 2))}

    monkeypatch.setattr(B, "cached_evaluation", fake_cached)
    monkeypatch.setattr(B, "dataset_seeds", lambda data: [1, 2])
    bundle = resolve_model_path("G16VV-cpu-zncc-fine")
    rows, _ = B.evaluate(tmp_path, scales.SCALES["cpu"],
                         {"new bundle": bundle, "previous bundle": bundle},
                         tests=("paper-test1",), lists=("train",),
                         readings={"new bundle": {"estimate": "mode", "mode_pick": 1}})
    keys = [k for k, _ in calls]
    assert [k["method"] for k in keys] == ["RS-E32", "new bundle", "previous bundle"]
    assert keys[1]["estimate"] == "mode" and keys[1]["mode_pick"] == 1
    assert "estimate" not in keys[2] and "mode_pick" not in keys[2]
    assert keys[1]["model"] == keys[2]["model"] == B.model_id(bundle)
    seen = []
    monkeypatch.setattr(B, "net_predictor", lambda *a, **k: seen.append(k))
    for _, make in calls[1:]:
        make("rig")
    assert seen == [{"estimate": "mode", "mode_pick": 1}, {}]
    assert [r["model"] for r in rows] == ["RS-E32", "new bundle", "previous bundle"]
