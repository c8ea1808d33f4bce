"""The paper's Table I on rendered data: every model evaluated on the training camera layout.

Trains E8, G8, E16, G16, G16V and G16VV on ``paper-train`` scenes (the -cpu presets at
``--scale cpu``, shrunk ones at ``--scale smoke``, the paper's at ``--scale paper``) and
evaluates them, with the classical RTSS baseline (RS-E16, RS-G16, RS-E32, RS-G32), on held-out
``paper-test1`` scenes (new scene seeds; see ``experiments/scales.py``). Columns: MAE, RMSE,
SSIM (inverse distance, 1/m), the share of pixels with an estimate, the median time of one
sample from raw fisheye images (ms) and the XLA peak memory of that call (MB). MAE, RMSE and SSIM
follow the paper's definitions (``gijax eval --metrics paper``: labels inside 0.5-100 m,
per-sample means, torchmetrics' SSIM); 'MAE (gijax)' beside them clamps labels to the range and
pools all pixels. Claims checked
from the table: (a) G8 is at least as good as E8; (c) the learned models beat the classical
baseline clearly.

Writes ``<out>.md``, ``<out>.json`` and ``<out>.png`` (inputs, ground truth, predictions and
error maps of the first test sample). Re-running reuses finished datasets, trainings and
evaluations from ``--work`` and resumes interrupted ones. ``new_layout.py`` reuses the runs.

    python experiments/same_layout.py --scale smoke      # about a minute: pipeline check
    python experiments/same_layout.py --scale cpu        # the reported figures (hours)
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.arguments import parse_script_args  # noqa: E402
from experiments.claims import (claim_gi_at_least_ev, claim_learned_beats_classical,
                                claims_markdown, print_claims)  # noqa: E402
from experiments.evaluation import (ROW_METRICS, cached_evaluation, net_predictor,
                                    rtss_predictor)  # noqa: E402
from experiments.provenance import provenance_markdown, provenance_record  # noqa: E402
from experiments.reporting import (fmt, log, save_figure, save_table,
                                   update_results_section)  # noqa: E402
from experiments.scales import PAPER_MAE_SAME, Scale  # noqa: E402
from experiments.workfolder import (check_held_out, ensure_dataset, ensure_trained,
                                    style_counts)  # noqa: E402
from gijax.bench.report import markdown_grid  # noqa: E402

NAME = "same_layout"
TEST = "paper-test1"


def prepare(scale: Scale, work: Path, tests: list, durations: dict) -> list:
    """Datasets (training, validation, ``tests``) and the trained models; dataset records."""
    t0 = time.perf_counter()
    roles = ["train"] + (["val"] if scale.val_samples else []) + list(tests)
    log(f"datasets ({scale.name} scale) in {work / 'data'}")
    data = [ensure_dataset(work, scale, role) for role in roles]
    check_held_out(work, list(tests))
    durations["data"] = time.perf_counter() - t0
    return data


def train_all(scale: Scale, work: Path, seed: int, durations: dict) -> dict:
    t0 = time.perf_counter()
    log(f"training {', '.join(scale.models)}")
    runs = {m: ensure_trained(work, scale, m, seed) for m in scale.models}
    durations["training"] = time.perf_counter() - t0
    # A rerun reuses finished trainings; their own durations were recorded when they ran.
    durations["training_recorded"] = sum(r.get("train_seconds", 0.0) for r in runs.values())
    return runs


def evaluate_rows(scale: Scale, work: Path, runs: dict, durations: dict) -> tuple[list, dict]:
    from gijax.baseline.rtss import get_rtss_preset
    from gijax.nn.presets import get_preset

    t0 = time.perf_counter()
    data = work / "data" / TEST
    n = scale.test_samples[TEST]
    rows, preds = [], {}
    for preset in scale.rtss_same:
        log(f"  evaluating {preset} on {TEST}")
        res = cached_evaluation(
            work, {"method": preset, "data": TEST, "samples": n, "scale": scale.name,
                   "pano": list(scale.pano_hw)},
            lambda rig, p=preset: rtss_predictor(rig, p, scale.pano_hw), data)
        config = get_rtss_preset(preset)
        rows.append(_row(preset, "classical", config.candidates.upper(), config.num_candidates,
                         res))
        preds[preset] = res["first_prediction"]
    for model, run in runs.items():
        log(f"  evaluating {run['preset']} on {TEST}")
        res = cached_evaluation(
            work, {"method": run["preset"], "train": run["command"], "data": TEST, "samples": n,
                   "candidates": "train"},
            lambda rig, r=run: net_predictor(Path(r["run"]), rig, "train"), data)
        mc = get_preset(run["preset"])
        rows.append(_row(model, "learned", mc.candidates.upper(), mc.num_candidates, res,
                         preset=run["preset"]))
        preds[model] = res["first_prediction"]
    durations["evaluation"] = time.perf_counter() - t0
    return rows, preds


def _row(model: str, kind: str, cand_type: str, num: int, res: dict, preset: str = "") -> dict:
    keep = ROW_METRICS
    return {"model": model, "preset": preset or model, "kind": kind, "cand_type": cand_type,
            "num_candidates": num, "status": "ok", "paper_mae": PAPER_MAE_SAME.get(model),
            **{k: res.get(k) for k in keep}}


def table_markdown(rows: list) -> str:
    header = ["model", "candidates", "num", "MAE", "RMSE", "SSIM", "MAE (gijax)", "coverage",
              "time (ms)", "peak (MB)", "paper MAE"]
    body = [[r["preset"], r["cand_type"], str(r["num_candidates"]), fmt(r["mae"]),
             fmt(r["rmse"]), fmt(r["ssim"]), fmt(r.get("mae_gijax")),
             fmt(r["coverage"], 3),
             fmt(r["time_ms"], 1), fmt(r["peak_mb"], 1), fmt(r["paper_mae"], 3)]
            for r in rows]
    return markdown_grid(header, body)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args, scale, work, out, results = parse_script_args(__doc__, NAME, argv)
    started = time.time()
    durations = {}

    data = prepare(scale, work, [TEST], durations)
    runs = train_all(scale, work, args.seed, durations)
    log(f"evaluating on {TEST}")
    rows, preds = evaluate_rows(scale, work, runs, durations)

    claims = [claim_gi_at_least_ev(rows), claim_learned_beats_classical(rows)]
    print_claims(claims, scale)
    from gijax.data import DatasetReader

    test_dir = work / "data" / TEST
    sample = DatasetReader(test_dir)[0]
    t0 = time.perf_counter()
    figure = out.with_suffix(".png")
    save_figure(figure, sample, [(r["preset"], preds[r["model"]]) for r in rows],
                  f"{TEST}, first held-out sample ({scale.name} scale)")
    durations["figure"] = time.perf_counter() - t0
    prov = provenance_record("same_layout.py", argv, scale, args.seed, work, started, durations,
                             data)
    prov["test_styles"] = {TEST: style_counts(test_dir)}
    doc = {"table": "same_layout", "test_data": TEST, "rows": rows, "claims": claims,
           "training": runs,
           "figure": figure.name, "provenance": prov}
    md = "\n\n".join([
        f"Models trained on `paper-train` scenes and tested on {sample_count(rows)} held-out "
        f"`{TEST}` scenes (inverse distance, 1/m; MAE, RMSE and SSIM as the paper defines "
        f"them: labels inside 0.5-100 m, per-sample means, torchmetrics' SSIM; 'MAE (gijax)' "
        f"clamps labels to the range and pools all pixels; time: median per sample from raw "
        f"fisheye images; peak: XLA memory analysis of that call).",
        table_markdown(rows), "## Claims", claims_markdown(claims, scale),
        f"![first test sample]({figure.name})", "## Provenance", provenance_markdown(prov)])
    save_table(out, "Same camera layout (Table I analogue)", md, doc)
    log(f"wrote {out.with_suffix('.md')}, {out.with_suffix('.json')} and {figure}")
    if results is not None:
        rel = Path(figure).resolve().relative_to(results.resolve().parent) \
            if Path(figure).resolve().is_relative_to(results.resolve().parent) else figure
        update_results_section(results, NAME, md.replace(f"]({figure.name})", f"]({rel})"))
        log(f"updated the {NAME} section of {results}")
    return 0


def sample_count(rows: list) -> int:
    return int(rows[0]["samples"]) if rows else 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
