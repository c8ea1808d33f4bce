"""``gijax eval``: the paper's table columns (MAE, RMSE, SSIM, coverage, time, memory) for a
trained run or the classical baseline."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

# One line per --metrics choice, written beside the numbers (gijax.evaluate.metrics has the
# full definitions).
METRIC_DEFINITIONS = {
    "paper": ("the paper's: per-sample MAE / RMSE / bad rates over labels inside the candidate "
              "range (excluded, not clamped, outside it), torchmetrics SSIM (11x11 Gaussian, "
              "sigma 1.5, data range from the sample, reflect padding, 5-px border cropped) "
              "against labels clamped to the range; means over samples"),
    "gijax": ("gijax's: labels clamped to the candidate range, MAE / RMSE / bad rates pooled "
              "over all usable pixels, SSIM with data range 1 and zero padding over the whole "
              "image; SSIM averaged over samples"),
}


def register(subparsers) -> None:
    from gijax.cli.options import (CKPT_HELP, HelpFormatter, add_candidates_option,
                                   add_estimate_option, add_method_option, add_rig_option,
                                   add_rtss_preset_option)

    p = subparsers.add_parser(
        "eval", help="evaluate a trained run (or the RTSS baseline) on a dataset folder",
        description=(
            "Evaluate a run folder on a dataset: MAE, RMSE and SSIM on inverse distance (1/m), "
            "the bad-pixel rates > 0.1 and > 0.4 1/m, time per sample and peak memory. "
            "--metrics picks the definitions (see gijax.evaluate.metrics): 'paper' (default) as "
            "the paper's tables computed them, MAE / RMSE / bad rates per sample over labels "
            "inside the candidate range (0.5-100 m; sky and nearer pixels left out) and "
            "torchmetrics' SSIM (data range from the sample, reflect padding, 5-px border "
            "cropped), averaged over samples; 'gijax' with labels clamped to the candidate "
            "range (sky and near pixels scored), errors pooled over all pixels and SSIM with "
            "data range 1 and zero padding. --rig evaluates on another rig than the dataset's "
            "(the paper's layout-change experiment) and --candidates picks the list: the "
            "training list, the paper's list recomputed for the evaluation rig ('spacing'), "
            "gijax's rig-aware GI ('rig'), EV, or a file. --method rtss evaluates the classical "
            "baseline instead: it needs no --ckpt (and refuses one, which it would not use); "
            "its default candidates are the --rtss-preset's own list (RS-E32: 32 even in "
            "inverse distance, 0.5-100 m), printed at run time, and its panorama is the "
            "dataset's. Pixels a method leaves without an estimate are lost coverage: left "
            "out of MAE, RMSE and the bad rates, reported as 'cov' (the share of scored "
            "pixels with an estimate) and seen by SSIM at the far end of the candidate "
            "range; no metric is NaN because of them."),
        formatter_class=HelpFormatter)
    p.add_argument("--ckpt", default=None, metavar="PATH|NAME",
                   help=CKPT_HELP + " (needed for --method learned; refused with --method rtss)")
    p.add_argument("--data", required=True,
                   help="dataset folder, gijax's layout or the release's (partition 'validate'; "
                        "DIR@KEY reads partition KEY)")
    add_rig_option(p, default_help="the dataset's rig")
    add_candidates_option(p, None, "'train' for --method learned, the RTSS preset's own list "
                                   "for --method rtss")
    add_estimate_option(p)
    p.add_argument("--which", default="best", choices=["best", "latest"],
                   help="checkpoint to load: best validated or newest periodic (an unreadable "
                        "one is skipped with a warning; the run folder is only read)")
    add_method_option(p, aliases=True)
    add_rtss_preset_option(p)
    p.add_argument("--batch", type=int, default=1, help="samples per forward pass")
    p.add_argument("--limit", type=int, default=0, help="evaluate at most this many samples")
    p.add_argument("--metrics", default="paper", choices=("paper", "gijax"),
                   help="metric definitions: 'paper' (as the paper's tables) or 'gijax' "
                        "(clamped labels, pooled pixels, fixed-range SSIM; the validation "
                        "metric of 'gijax train')")
    p.add_argument("--json", default=None, help="write the results to this JSON file "
                                                 "(records the metric definitions used, and "
                                                 "each sample's metrics under 'per_scene' for "
                                                 "paired comparisons)")
    p.add_argument("--allow-partial", action="store_true",
                   help="evaluate on a dataset holding fewer samples than its manifest requests")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar (on stderr) while the samples are evaluated")
    p.set_defaults(func=run)


def _rtss_setup(args, rig, reader):
    """The rig at the dataset's image size, the RTSS configuration, its candidates with their
    description, and the output panorama (the dataset's label panorama)."""
    from gijax.baseline.rtss import choose_candidates, get_rtss_preset
    from gijax.data.images import fit_images

    if args.ckpt:
        raise ValueError("--method rtss evaluates the classical baseline, which uses no model; "
                         "drop --ckpt (or use --method learned)")
    config = get_rtss_preset(args.rtss_preset)
    first = reader[0]
    # The size policy of 'gijax predict': the baseline works at the images' own size.
    rig = fit_images(rig, first["images"], None, None,
                     log=lambda line: print(line, file=sys.stderr))[0]
    config = config.replace(match_size=min(config.match_size, rig.cameras[0].width))
    cand, how = choose_candidates(args.candidates, rig, config)
    pano = reader.pano
    return rig, config, cand, how, pano


def run(args) -> int:
    import jax

    from gijax.bench.memory import device_peak_mib, host_peak_rss_mib
    from gijax.candidates.spec import model_candidates
    from gijax.evaluate.loop import evaluate_predictions
    from gijax.predict import RtssBatchPredictor, learned_batch_predictor, sample_batches
    from gijax.store import load_model
    from gijax.train.sources import open_dataset, validation_batches

    if args.batch < 1:
        raise ValueError(f"--batch must be >= 1; found {args.batch}")
    if args.json:
        from gijax.io.paths import check_output_file

        check_output_file(args.json, "--json")
    if args.method == "learned" and not args.ckpt:
        raise ValueError("--method learned needs --ckpt (a run folder, bundle or bundled model); "
                         "--method rtss evaluates the classical baseline without one")
    if args.method == "rtss" and args.estimate:
        raise ValueError("--estimate reads a learned model's probabilities; --method rtss has "
                         "none (drop --estimate, or use --method learned)")
    if args.method == "learned":                 # a wrong model name is reported first
        model, mc, train_cand = load_model(args.ckpt, args.which)
        from gijax.model import with_estimate

        model = with_estimate(model, args.estimate)
        mc = model.config
    reader = open_dataset(args.data, "evaluation", args.allow_partial)
    if args.rig:
        from gijax.io.rigfile import load_rig

        # The labels fix the panorama frame: the dataset's, whatever the rig file says.
        rig = load_rig(args.rig).replace(panorama_rotation=reader.rig.panorama_rotation)
        if rig.num_cameras != reader.rig.num_cameras:
            raise ValueError(f"--rig {args.rig} has {rig.num_cameras} camera(s) but dataset "
                             f"{args.data} holds images of {reader.rig.num_cameras} "
                             f"({', '.join(reader.rig.names)}); give the dataset's rig")
    else:
        rig = reader.rig
    if args.method == "learned":
        cand, how = model_candidates(args.candidates or "train", rig, mc, train=train_cand)
        from gijax.model import coverage_note

        # The network runs on the labels' panorama (frame, coverage and size).
        note = coverage_note(mc, reader.pano)
        if note:
            print(note, file=sys.stderr)
        from gijax.store.envelope import warn_if_outside_training

        warn_if_outside_training(rig, args.ckpt, mc.name)
        predict = learned_batch_predictor(model, rig, cand, reader.pano)
        batches = validation_batches(reader, rig, args.batch, mc.surrogate_hw, 0)
        name = mc.name
    else:
        rig, config, cand, how, pano = _rtss_setup(args, rig, reader)
        predict = RtssBatchPredictor(rig, cand, pano, config)
        batches = sample_batches(reader, args.batch)
        name = f"{config.name}/rtss"
    print(f"candidates: {how}; {len(cand)} from {float(cand[0]):.3f} to {float(cand[-1]):.3f} m",
          file=sys.stderr)
    from tqdm import tqdm

    total = min(len(reader), args.limit) if args.limit else len(reader)
    with tqdm(total=total, desc=f"eval {name}", unit="sample", file=sys.stderr,
              disable=args.no_progress) as bar:
        evaluation = evaluate_predictions(batches, predict, cand, metric_sets=(args.metrics,),
                                          limit=args.limit, warmup=True,
                                          name=f"evaluation data {args.data}",
                                          on_batch=bar.update)
    metrics = evaluation.metrics[args.metrics]
    times = evaluation.seconds
    bad = sorted(k for k, v in metrics.items()
                 if isinstance(v, float) and not np.isfinite(v))
    if bad:
        raise ValueError(f"evaluation of {args.ckpt or args.method} on {args.data} gave "
                         f"non-finite metrics ({', '.join(f'{k} {metrics[k]}' for k in bad)}): "
                         f"no usable prediction; nothing was written")
    result = {"run": str(args.ckpt) if args.ckpt else None, "data": str(args.data),
              "method": args.method, "preset": name, "rig": args.rig or "dataset",
              "metric_set": args.metrics, "metric_definitions": METRIC_DEFINITIONS[args.metrics],
              "candidates_spec": args.candidates or "default", "candidates_how": how,
              "candidates": [float(c) for c in cand],
              "estimate": mc.estimate if args.method == "learned" else None, **metrics,
              "time_ms_per_sample": 1000.0 * float(np.mean(times)),
              "device": str(jax.local_devices()[0]), "host_peak_mb": host_peak_rss_mib(),
              # Each sample's own metrics, in dataset order, so that two methods can be
              # compared scene by scene (a paired test) without evaluating again.
              "per_scene": evaluation.per_scene(args.metrics)}
    device_peak = device_peak_mib()
    if device_peak is not None:
        result["device_peak_mb"] = device_peak
    mem = result.get("device_peak_mb", result["host_peak_mb"])
    print(f"{'model':<16}{'cand':>6}{'MAE':>9}{'RMSE':>9}{'SSIM':>8}{'>0.1':>8}{'>0.4':>8}"
          f"{'cov':>7}{'ms':>9}{'MB':>9}")
    print(f"{name:<16}{(args.candidates or 'def')[:6]:>6}"
          f"{metrics['mae']:>9.4f}{metrics['rmse']:>9.4f}{metrics['ssim']:>8.4f}"
          f"{metrics['bad_0.1']:>8.4f}{metrics['bad_0.4']:>8.4f}{metrics['coverage']:>7.3f}"
          f"{result['time_ms_per_sample']:>9.1f}{mem:>9.0f}")
    print(f"({metrics['samples']} samples; inverse distance in 1/m; {args.metrics} metrics: "
          f"{METRIC_DEFINITIONS[args.metrics]})", file=sys.stderr)
    if args.json:
        from gijax.train.config import write_json_atomic

        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(args.json, result)
    return 0
