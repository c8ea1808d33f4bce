"""CPU-scale designs compared at an equal budget of training time: which network to train long.

The bundled ``G16VV-cpu`` ties the classical baseline on the training layout; its error sits on
depth edges, where its 16 x 64 cost volume (5.6 degrees a cell) is coarser than the 256 px
images RTSS matches on. Each design here spends the CPU differently (``gijax.nn.presets``):

* ``G16VV-cpu``: the bundle's design (cost volume 16 x 64, output 32 x 128);
* ``G16VV-cpu-fine``: the cost volume at the output's 32 x 128 (a cell per feature pixel);
* ``G32VV-cpu``: 32 candidates instead of 16;
* ``G16VV-cpu-refine``: a guided refinement after the soft-argmax, at the output's resolution,
  from the cameras' colours at the estimated distance (:mod:`gijax.nn.refine`);
* ``G16VV-cpu-zncc``: the classical matching cost (the cameras' mean pairwise ZNCC of 4 x 4
  grey samples per cell, :mod:`gijax.sweep.matching`) as a cost-volume channel beside the
  learned features, so that the network starts from what the baseline measures;
* ``G16VV-cpu-wide``: fewer, wider feature layers (16 channels, 2 residual blocks at the
  feature resolution, against 8 channels in 2 + 3 blocks).

Every design trains from random weights (seed 0) on the bundle's data (the rig-and-lens
mixture of ``experiments/bundle_model.py``, same augmentation, calibration errors and
schedule shape) for the same *budget of training seconds*: each design's seconds per step
are measured side by side with the reference design's (alternating rounds, one process,
batch 8) and its step count is the budget divided by them. The measurements are stored in
``budget.json`` beside the results and reused, so that a comparison trained in pieces on
several machines keeps its step counts (:func:`measure_budget`). The designs train in turns, a slice of each budget at a time, so that a
stop leaves them at equal shares; each run keeps a resume pack under ``experiments/packs/``
(commit it at a stop; the same command continues). Validation MAE (24 held-out
``paper-train`` scenes) is logged along the way and plotted against training seconds; a
finished design is also evaluated on the held-out ``paper-test1`` scenes beside RS-E32.

    python experiments/design_comparison.py --scale smoke      # pipeline check
    python experiments/design_comparison.py --scale cpu        # 45 min of training per design
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments import bundle_model as BM  # noqa: E402
from experiments.arguments import (EXPERIMENTS, add_common_arguments,  # noqa: E402
                                   resolve_paths, script_parser)
from experiments.provenance import provenance_markdown, provenance_record, revision  # noqa: E402
from experiments.reporting import (fmt, log, publish_section, read_json, save_png,  # noqa: E402
                                   save_table, write_json)
from experiments.scales import SCALES, Scale, design_overrides  # noqa: E402
from experiments.workfolder import gijax_command, metrics_records, train_run  # noqa: E402

NAME = "design_comparison"
DESIGNS = ("G16VV-cpu", "G16VV-cpu-fine", "G32VV-cpu", "G16VV-cpu-refine", "G16VV-cpu-zncc",
           "G16VV-cpu-wide")
TEST = "paper-test1"


@dataclasses.dataclass(frozen=True)
class Budget:
    """How much each design trains at one scale."""

    seconds: float        # training seconds per design
    batch: int
    pieces: int           # turns: each design trains 1 / pieces of its budget per turn
    timing_steps: int     # steps per timing round
    timing_rounds: int
    val_points: int       # validations per design over its budget
    ckpt_every: int       # steps between checkpoints (and pack rewrites)
    min_steps: int = 1


BUDGETS = {
    "smoke": Budget(seconds=1.0, batch=2, pieces=2, timing_steps=1, timing_rounds=1,
                    val_points=1, ckpt_every=1, min_steps=2),
    "cpu": Budget(seconds=2700.0, batch=8, pieces=3, timing_steps=3, timing_rounds=3,
                  val_points=6, ckpt_every=50),
}


def design_preset(scale: Scale, design: str) -> str:
    return design if scale.name != "paper" else design.replace("-cpu", "")


def overrides(scale: Scale, design: str) -> dict:
    """The scale's shrinking of the bundle's model (smoke), kept consistent per design."""
    return design_overrides(scale, design)


# --------------------------------------------------------------------------- budget

def measure_budget(scale: Scale, budget: Budget, path: Path, measure: bool = True) -> dict:
    """Seconds per step of every design and the step counts they give, kept in ``path``.

    Machines differ (this project's 2-core machines have run 2.4x apart), so a design's cost is
    stored as its time relative to the reference design (the first of :data:`DESIGNS`),
    measured side by side with it in alternating rounds, and its step count is the budget
    over that ratio times the reference's seconds per step of the first measurement. A design
    added later is measured beside the reference on whatever machine runs then, and the
    designs already measured keep their step counts. ``measure=False`` only reads ``path``.
    """
    from gijax.bench.machine import invocation
    from gijax.bench.train_step import alternating_step_seconds, train_step_case

    key = {"batch": budget.batch, "seconds": budget.seconds, "scale": scale.name,
           "reference": DESIGNS[0]}
    doc = read_json(path)
    if not doc or doc.get("key") != key:
        doc = {"key": key, "reference_s_per_step": None, "ratio": {}, "steps": {},
               "s_per_step": {}, "measurements": []}
    missing = [d for d in DESIGNS if d not in doc["ratio"]]
    if not missing or not measure:
        log(f"budget: the step counts of {path} ({len(doc['measurements'])} measurement(s))")
        return doc
    timed = [DESIGNS[0]] + [d for d in missing if d != DESIGNS[0]]
    log(f"budget: timing {', '.join(timed)} side by side (batch {budget.batch}, "
        f"{budget.timing_rounds} alternating rounds)")
    cases = [train_step_case(design_preset(scale, d), budget.batch, overrides(scale, d))
             for d in timed]
    per = alternating_step_seconds(cases, budget.timing_steps, budget.timing_rounds,
                                   progress=lambda line: log("  " + line))
    per = {d: per[design_preset(scale, d)] for d in timed}
    if doc["reference_s_per_step"] is None:
        doc["reference_s_per_step"] = per[DESIGNS[0]]
    for d in missing:
        doc["ratio"][d] = per[d] / per[DESIGNS[0]]
        doc["s_per_step"][d] = doc["ratio"][d] * doc["reference_s_per_step"]
        doc["steps"][d] = max(int(budget.seconds / doc["s_per_step"][d]), budget.min_steps)
    doc["measurements"].append({"s_per_step": per,
                                "compile_s": {d: c.compile_s for d, c in zip(timed, cases)},
                                **invocation("design_comparison budget")})
    write_json(path, doc)
    return doc


# --------------------------------------------------------------------------- training

def train_config(scale: Scale, budget: Budget, design: str, steps: int, seed: int, pack):
    from gijax.train.config import TrainConfig

    recipe = BM.RECIPES[scale.name]
    return TrainConfig(preset=design_preset(scale, design),
                       model_overrides=overrides(scale, design), lr=recipe.lr,
                       schedule="warmup_cosine", warmup_steps=max(steps // 20, 1),
                       batch_size=budget.batch, steps=steps, seed=seed,
                       val_every=max(steps // budget.val_points, 1),
                       ckpt_every=min(budget.ckpt_every, steps), keep_best=True,
                       workers=recipe.workers, augment=recipe.augment,
                       calibration_error_deg=recipe.calibration_deg,
                       pack=None if pack is None else str(pack))


def train_argv(work: Path, data: list, cfg) -> list:
    """The ``gijax train`` command equivalent to the run (it keys the run's reuse)."""
    argv = ["train", "--preset", cfg.preset, "--data", *data, "--val", work / "data" / "val",
            "--out", work / "runs" / f"design-{cfg.preset}", "--steps", cfg.steps,
            "--batch", cfg.batch_size, "--lr", cfg.lr, "--schedule", cfg.schedule,
            "--warmup-steps", cfg.warmup_steps, "--val-every", cfg.val_every,
            "--ckpt-every", cfg.ckpt_every, "--seed", cfg.seed, "--workers", cfg.workers,
            "--augment", cfg.augment, "--calibration-error", cfg.calibration_error_deg]
    if cfg.pack:
        argv += ["--pack", cfg.pack]
    for k, v in cfg.model_overrides.items():
        argv += ["--override", f"{k}={json.dumps(v, separators=(',', ':'))}"]
    return argv


def pack_folder(scale: Scale, design: str, out: Path) -> Path:
    """Committed packs for the reported scale; the other scales keep theirs with the output."""
    if scale.name == "cpu":
        return EXPERIMENTS / "packs" / f"design-{design}"
    return out / "packs" / f"design-{design}"


def train_designs(work: Path, scale: Scale, budget: Budget, measured: dict, seed: int,
                  out: Path) -> dict:
    """Train every design to its step count, in ``budget.pieces`` turns; run records."""
    data = [str(work / "data" / role) for role, _, _ in BM.mixture_roles(BM.RECIPES[scale.name])]
    records = {}
    for piece in range(1, budget.pieces + 1):
        for design in DESIGNS:
            steps = int(measured["steps"][design])
            cfg = train_config(scale, budget, design, steps, seed,
                               pack_folder(scale, design, out))
            run = work / "runs" / f"design-{cfg.preset}"
            stop = math.ceil(steps * piece / budget.pieces)
            log(f"design {design}: turn {piece}/{budget.pieces}, to step {stop} of {steps}")
            records[design] = train_run(run, gijax_command(train_argv(work, data, cfg)), cfg,
                                        data, work / "data" / "val", scale.progress,
                                        {"design": design}, stop_at=stop)
    return records


# --------------------------------------------------------------------------- report

def curves(work: Path, measured: dict) -> dict:
    """Per measured design: [(training seconds, step, validation MAE)] from its log."""
    out = {}
    for design in (d for d in DESIGNS if d in measured["s_per_step"]):
        run = work / "runs" / f"design-{design}"
        per = measured["s_per_step"][design]
        out[design] = [(r["step"] * per, r["step"], r["mae"]) for r in metrics_records(run)
                       if r.get("split") == "val"]
    return out


def trained_steps(work: Path) -> dict:
    """Per design: the last step its log records."""
    return {d: max([int(r["step"]) for r in metrics_records(work / "runs" / f"design-{d}")
                    if "loss" in r], default=0) for d in DESIGNS}


def plot(curve: dict, budget_s: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0), layout="constrained")
    for design, pts in curve.items():
        if pts:
            ax.plot([p[0] / 60 for p in pts], [p[2] for p in pts], marker="o", label=design)
    ax.axvline(budget_s / 60, color="0.6", ls=":", lw=1)
    ax.set_xlabel("training time, minutes (each design's measured seconds per step x steps)")
    ax.set_ylabel("validation MAE, 1/m (24 paper-train scenes)")
    ax.set_title("CPU-scale designs at an equal training budget")
    ax.grid(alpha=0.3)
    ax.legend()
    save_png(fig, path, dpi=110)
    plt.close(fig)


def table(measured: dict, curve: dict, tests: dict, trained: dict) -> str:
    from gijax.nn.presets import get_preset
    from gijax.store.assets import parameter_count

    lines = ["| design | cost volume | parameters | s / step | steps in budget | trained | "
             "best val MAE | last val MAE | paper-test1 MAE (RS-E32) |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for d in DESIGNS:
        cfg = get_preset(d)
        if d not in curve:
            lines.append(f"| `{d}` | {cfg.num_candidates} x {cfg.cost_hw[0]} x {cfg.cost_hw[1]} "
                         f"| {parameter_count(cfg) / 1e6:.2f} M | not timed yet | | | | | |")
            continue
        pts = curve[d]
        best = min((p[2] for p in pts), default=None)
        last = pts[-1] if pts else None
        test = tests.get(d)
        lines.append(
            f"| `{d}` | {cfg.num_candidates} x {cfg.cost_hw[0]} x {cfg.cost_hw[1]} | "
            f"{parameter_count(cfg) / 1e6:.2f} M | {measured['s_per_step'][d]:.2f} | "
            f"{measured['steps'][d]} | {trained[d]} | {fmt(best)} | "
            f"{fmt(last[2] if last else None)} | "
            f"{fmt(test['model']) + ' (' + fmt(test['rtss']) + ')' if test else '-'} |")
    return "\n".join(lines)


def evaluate_finished(work: Path, scale: Scale, records: dict) -> dict:
    """paper-test1 MAE of each finished design and RS-E32's, from the cached evaluations."""
    from experiments.workfolder import ensure_dataset

    done = {d: Path(r["run"]) for d, r in records.items() if r.get("finished", True)}
    if not done:
        return {}
    ensure_dataset(work, scale, TEST)
    rows, _ = BM.evaluate(work, scale, done, tests=(TEST,), lists=("train",))
    rtss = BM.mae_of(rows, TEST, BM.RTSS, "ev")
    return {d: {"model": BM.mae_of(rows, TEST, d, "train"), "rtss": rtss} for d in done}


def main(argv=None) -> int:
    started = time.time()
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = script_parser(__doc__)
    add_common_arguments(parser, NAME)
    parser.add_argument("--report-only", action="store_true",
                        help="train nothing: report the designs as far as their runs (or "
                             "packs) have come, e.g. at a stop between two turns")
    parser.add_argument("--budget-minutes", type=float, default=None,
                        help="training minutes per design (default: 45 at --scale cpu); the "
                             "step counts come from one side-by-side timing, stored in "
                             "budget.json and reused")
    args = parser.parse_args(argv)
    if args.scale == "paper":
        parser.error("the design comparison is a CPU-scale experiment (--scale smoke or cpu)")
    scale = SCALES[args.scale]
    budget = BUDGETS[scale.name]
    if args.budget_minutes is not None:
        if not args.budget_minutes > 0:
            parser.error(f"--budget-minutes must be positive; found {args.budget_minutes}")
        budget = dataclasses.replace(budget, seconds=60.0 * args.budget_minutes)
    work, out, results = resolve_paths(args, NAME)
    out.mkdir(parents=True, exist_ok=True)
    recipe = BM.RECIPES[scale.name]
    log(f"datasets ({scale.name} scale) in {work / 'data'}")
    t0 = time.perf_counter()
    data = [BM.ensure_mixture_dataset(work, scale, recipe, i, *r)
            for i, r in enumerate(BM.mixture_roles(recipe))]
    from experiments.workfolder import ensure_dataset

    data.append(ensure_dataset(work, scale, "val"))
    durations = {"data_s": time.perf_counter() - t0}
    measured = measure_budget(scale, budget, out / "budget.json", measure=not args.report_only)
    t0 = time.perf_counter()
    if args.report_only:
        records = {d: {"run": str(work / "runs" / f"design-{design_preset(scale, d)}"),
                       "finished": False} for d in DESIGNS if d in measured["steps"]}
    else:
        records = train_designs(work, scale, budget, measured, args.seed, out)
    durations["train_s"] = time.perf_counter() - t0
    tests = evaluate_finished(work, scale, records)
    curve = curves(work, measured)
    figure = out / "design_comparison.png"
    plot(curve, budget.seconds, figure)
    body = table(measured, curve, tests, trained_steps(work))
    prov = provenance_record(f"{NAME}.py", argv, scale, args.seed, work, started, durations,
                             data)
    doc = {"budget": dataclasses.asdict(budget), "measured": measured, "curves": curve,
           "tests": tests, "records": records, "provenance": prov, "revision": revision()}
    save_table(out / NAME, "CPU-scale designs at an equal training budget", body, doc)
    if results is not None:
        done = all(r.get("finished", True) for r in records.values())
        state = "" if done else ("**In progress**: the designs train in turns; the rows show "
                                 "how far each has come, at equal shares of the budget.\n\n")
        text = (f"{state}Each design trains from random weights on the bundle's mixture for "
                f"{budget.seconds / 60:.0f} minutes of training (its seconds per step at batch "
                f"{budget.batch} relative to `{DESIGNS[0]}`'s, measured side by side in alternating "
                f"rounds, times its steps; `budget.json` holds the measurements). The runs "
                f"are trained by `python experiments/design_comparison.py --scale "
                f"{scale.name}` in pieces; each piece's command, revision and host are in its "
                f"pack's `metrics.jsonl` (`experiments/packs/`).\n\n"
                f"{body}\n\n![validation MAE against training time]({figure.name})\n\n"
                f"{provenance_markdown(prov)}")
        publish_section(results, NAME, text, [figure])
    log(body)
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
