"""``gijax eval``: the paper's table columns (MAE, RMSE, SSIM, time, memory) for a trained run."""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

METHODS = ("net", "rtss")
# One line per --metrics choice, written beside the numbers (gijax.train.metrics has the
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
    p = subparsers.add_parser(
        "eval", help="evaluate a trained run (or the RTSS baseline) on a dataset folder",
        description=(
            "Evaluate a run folder on a dataset: MAE, RMSE and SSIM on inverse distance (1/m), "
            "the bad-pixel rates > 0.1 and > 0.4 1/m, time per sample and peak memory. "
            "--metrics picks the definitions (see gijax.train.metrics): 'paper' (default) as "
            "the paper's tables computed them, MAE / RMSE / bad rates per sample over labels "
            "inside the candidate range (0.5-100 m; sky and nearer pixels left out) and "
            "torchmetrics' SSIM (data range from the sample, reflect padding, 5-px border "
            "cropped), averaged over samples; 'gijax' with labels clamped to the candidate "
            "range (sky and near pixels scored), errors pooled over all pixels and SSIM with "
            "data range 1 and zero padding. --rig evaluates on another rig than the dataset's "
            "(the paper's layout-change experiment) and --candidates picks the list: the "
            "training list, the paper's list recomputed for the evaluation rig ('spacing'), "
            "gijax's rig-aware GI ('rig'), EV, or a file."),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--ckpt", required=True, help="run folder written by 'gijax train', or an inference bundle")
    p.add_argument("--data", required=True,
                   help="dataset folder, gijax's layout or the release's (partition 'validate'; "
                        "DIR@KEY reads partition KEY)")
    p.add_argument("--rig", default=None, help="rig name or file (default: the dataset's rig)")
    p.add_argument("--candidates", default="train",
                   help="'train' (training list); 'spacing' (the paper's list for a new rig, "
                        "Table II: closed-form GI with the rig's camera spacing as the "
                        "baseline); 'rig' (gijax's extension: rig-aware GI, equal mean pixel "
                        "steps over the panorama's rays and cameras; on the training rig it is "
                        "close to EV, not to the released G16); 'ev'; or a JSON / text file of "
                        "distances in metres")
    p.add_argument("--which", default="best", choices=["best", "latest"],
                   help="checkpoint to load: best validated or newest periodic (an unreadable "
                        "one is skipped with a warning; the run folder is only read)")
    p.add_argument("--method", default="net", choices=METHODS,
                   help="'net' (the trained network) or 'rtss' (the classical baseline with the "
                        "same candidates)")
    p.add_argument("--batch", type=int, default=1, help="samples per forward pass")
    p.add_argument("--limit", type=int, default=0, help="evaluate at most this many samples")
    p.add_argument("--metrics", default="paper", choices=("paper", "gijax"),
                   help="metric definitions: 'paper' (as the paper's tables) or 'gijax' "
                        "(clamped labels, pooled pixels, fixed-range SSIM; the validation "
                        "metric of 'gijax train')")
    p.add_argument("--json", default=None, help="write the results to this JSON file "
                                                 "(records the metric definitions used)")
    p.add_argument("--allow-partial", action="store_true",
                   help="evaluate on a dataset holding fewer samples than its manifest requests")
    p.set_defaults(func=run)


def choose_candidates(spec: str, train_candidates, model_config, rig) -> np.ndarray:
    """The evaluation candidate list (metres) for ``--candidates``."""
    from gijax.candidates import RECOMPUTED, recomputed_candidates

    n = model_config.num_candidates
    if spec == "train":
        cand = np.asarray(train_candidates, np.float64)
    elif spec in RECOMPUTED:
        cand = np.asarray(recomputed_candidates(spec, n, rig, model_config.d_min,
                                                model_config.d_max), np.float64)
    else:
        from gijax.cli.cmd_train import read_candidate_file

        cand = np.asarray(read_candidate_file(spec), np.float64)
    if cand.shape != (n,):
        raise ValueError(f"the network uses {n} candidates; --candidates {spec} gives {cand.size}")
    if cand[0] <= 0 or np.any(np.diff(cand) <= 0):
        raise ValueError(f"candidates must be positive, strictly ascending metres; found {cand}")
    return cand


def peak_memory_mb() -> dict:
    """Peak host RSS and, where the backend reports it, peak device memory (MB)."""
    import jax

    out = {"host_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
    stats = jax.local_devices()[0].memory_stats() or {}
    if "peak_bytes_in_use" in stats:
        out["device_peak_mb"] = stats["peak_bytes_in_use"] / 2 ** 20
    return out


def _net_predictor(model, rig, candidates):
    import jax
    import jax.numpy as jnp
    from flax import nnx

    graphdef, state = nnx.split(model)

    @jax.jit
    def forward(state, images, masks, rig, cand):
        return nnx.merge(graphdef, state)(images, masks, rig, cand)["inv_distance"]

    cand = jnp.asarray(candidates, jnp.float32)
    from gijax.train.trainer import model_rig

    mrig = model_rig(rig)

    def predict(batch, _reader, _indices):
        return forward(state, jnp.asarray(batch["images"]), jnp.asarray(batch["masks"]), mrig, cand)

    return predict


def _rtss_predictor(rig, candidates, pano):
    """RTSS on the raw fisheye images of each sample (the baseline engineer's rtss_predict)."""
    import jax.numpy as jnp

    from gijax.baseline.rtss import rtss_predict

    cand = jnp.asarray(candidates, jnp.float32)

    def predict(_batch, reader, indices):
        outs = []
        for i in indices:
            s = reader[int(i)]
            images = np.asarray(s["images"], np.float32) / 255.0
            outs.append(rtss_predict(rig, images, np.asarray(s["masks"], np.float32), cand,
                                     pano)["inv_distance"])
        return jnp.stack(outs)

    return predict


def run(args) -> int:
    import jax
    import jax.numpy as jnp

    from gijax.geometry.panorama import Panorama
    from gijax.train.metrics import batch_sums, summarize
    from gijax.train.sources import open_dataset, validation_batches
    from gijax.train.bundle import is_bundle, load_bundle
    from gijax.train.trainer import load_for_inference

    if args.batch < 1:
        raise ValueError(f"--batch must be >= 1; found {args.batch}")
    if args.json:
        from gijax.io.paths import check_output_file

        check_output_file(args.json, "--json")
    if is_bundle(args.ckpt):
        model, mc, train_cand = load_bundle(args.ckpt)
    else:
        model, mc, train_cand = load_for_inference(args.ckpt, args.which)
    reader = open_dataset(args.data, "evaluation", args.allow_partial)
    if args.rig:
        from gijax.io.rigfile import load_rig

        rig = load_rig(args.rig)
    else:
        rig = reader.rig
    cand = choose_candidates(args.candidates, np.asarray(train_cand), mc, rig)
    jcand = jnp.asarray(cand, jnp.float32)
    pano = Panorama.hemisphere(*mc.output_hw)
    if args.method == "net":
        predict = _net_predictor(model, rig, cand)
    else:
        predict = _rtss_predictor(rig, cand, pano)
    parts, times, seen = [], [], 0
    for batch in validation_batches(reader, rig, args.batch, mc.surrogate_hw, 0):
        if args.limit and seen >= args.limit:
            break
        indices = batch["index"]
        if seen == 0:                       # compile outside the timing
            jax.block_until_ready(predict(batch, reader, indices))
        t0 = time.perf_counter()
        inv = jax.block_until_ready(predict(batch, reader, indices))
        times.append((time.perf_counter() - t0) / len(indices))
        sums = batch_sums(inv, jnp.asarray(batch["distance"]), jnp.asarray(batch["valid"]), jcand,
                          metric_set=args.metrics)
        parts.append(jax.tree.map(np.asarray, sums))
        seen += len(indices)
    if not parts:
        raise ValueError(f"evaluation data {args.data} yielded no samples")
    metrics = summarize({k: np.concatenate([p[k] for p in parts]) for k in parts[0]},
                        args.metrics)
    result = {"run": str(args.ckpt), "data": str(args.data), "method": args.method,
              "preset": mc.name, "rig": args.rig or "dataset", "metric_set": args.metrics,
              "metric_definitions": METRIC_DEFINITIONS[args.metrics],
              "candidates_spec": args.candidates,
              "candidates": [float(c) for c in cand], **metrics,
              "time_ms_per_sample": 1000.0 * float(np.mean(times)),
              "device": str(jax.local_devices()[0]), **peak_memory_mb()}
    mem = result.get("device_peak_mb", result["host_peak_mb"])
    print(f"{'model':<14}{'cand':>6}{'MAE':>9}{'RMSE':>9}{'SSIM':>8}{'>0.1':>8}{'>0.4':>8}"
          f"{'ms':>9}{'MB':>9}")
    print(f"{mc.name + ('/rtss' if args.method == 'rtss' else ''):<14}{args.candidates[:6]:>6}"
          f"{metrics['mae']:>9.4f}{metrics['rmse']:>9.4f}{metrics['ssim']:>8.4f}"
          f"{metrics['bad_0.1']:>8.4f}{metrics['bad_0.4']:>8.4f}"
          f"{result['time_ms_per_sample']:>9.1f}{mem:>9.0f}")
    print(f"({metrics['samples']} samples; inverse distance in 1/m; {args.metrics} metrics: "
          f"{METRIC_DEFINITIONS[args.metrics]})", file=sys.stderr)
    if args.json:
        from gijax.train.config import write_json_atomic

        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(args.json, result)
    return 0
