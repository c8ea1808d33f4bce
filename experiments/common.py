"""Shared machinery of the paper-table experiments (``same_layout.py`` and ``new_layout.py``).

Both scripts share one work folder (``--work``): rendered datasets under ``data/``, training run
folders under ``runs/`` and cached evaluations under ``evals/``. Everything is resumable: a
dataset continues after its last complete sample, an interrupted training resumes from the
trainer's newest checkpoint, a finished training (``runs/<preset>.done.json``) and a finished
evaluation (``evals/<key>.json``) are reused as they are.

Data and seeds (fixed per role, never chosen by looking at test results):

* training: ``paper-train``, dataset seed 1, style 'mixed' (indoor and outdoor scenes);
* validation (picks the best checkpoint): ``paper-train``, dataset seed 2;
* tests: ``paper-test1`` seed 101, ``paper-test2`` seed 102, ``paper-test3`` seed 103.

Sample ``i`` of a dataset with seed ``s`` is rendered from ``sample_seed(s, i)``, so test scenes
are new random scenes (layout, objects, materials, lighting, exposure); the scripts check that
no test sample seed occurs in the training or validation data. The renderer has two scene
styles and the training data holds both, so held-out scenes differ from the training scenes by
seed, not by style family (training on one style only would confound the candidate claims with
a domain shift).

Metrics (:mod:`gijax.train.metrics`, inverse distance in 1/m): the columns compared with the
paper's figures (``mae``, ``rmse``, ``ssim``, ``bad_0.1``, ``bad_0.4``) use the paper's
definitions, ``gijax eval --metrics paper``: per-sample MAE / RMSE over labels inside the
candidate range (0.5-100 m; sky and nearer pixels excluded), torchmetrics' SSIM, means over
samples. gijax's own definitions (labels clamped to the range, pooled pixels, fixed-range SSIM)
are kept beside them with a ``_gijax`` suffix. The classical baseline leaves a few pixels
without an estimate: MAE and RMSE are taken over its estimated pixels (``coverage`` reports
their share) and SSIM fills the holes with the farthest candidate.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import platform
import resource
import shlex
import subprocess
import time
from pathlib import Path
from typing import Callable, Optional

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = Path(__file__).resolve().parent

TEST_RIGS = ("paper-test1", "paper-test2", "paper-test3", "paper-train-1m")
DATA_SEEDS = {"train": 1, "val": 2, "paper-test1": 101, "paper-test2": 102, "paper-test3": 103,
              "paper-train-1m": 104}
DATA_STYLE = "mixed"
MODELS = ("E8", "G8", "E16", "G16", "G16V", "G16VV")

# Identifies the metric definitions of cached evaluations (evals/<key>.json): the paper's
# columns plus gijax's beside them. Change it when a definition changes.
METRICS_VERSION = "paper+gijax-1"

# "Clearly better" in claim (c): a learned model's MAE at most this fraction of the best
# classical configuration's MAE on the same test data (fixed before any cpu-scale run).
CLEAR_FACTOR = 0.75

# REFERENCE section 6: the paper's MAE (1/m) for the side-by-side column. The paper's RTSS used
# the 1x1 AD cost, so its figures stand beside both the ZNCC presets and RS-E32-AD.
PAPER_MAE_SAME = {"RS-E16": 0.075, "RS-G16": 0.076, "RS-E32": 0.053, "RS-G32": 0.059,
                  "RS-E32-AD": 0.053,
                  "E8": 0.013, "G8": 0.012, "E16": 0.011, "G16": 0.010, "G16V": 0.013,
                  "G16VV": 0.012}
# Table II's recomputed list is the closed form at the new camera spacing: gijax's 'spacing'.
PAPER_MAE_NEW = {("paper-test2", "RS-E32", "ev"): 0.124,
                 ("paper-test2", "E16", "train"): 0.033, ("paper-test2", "E16", "spacing"): 0.018,
                 ("paper-test2", "G16", "train"): 0.030, ("paper-test2", "G16", "spacing"): 0.020,
                 ("paper-test2", "G16V", "train"): 0.030,
                 ("paper-test2", "G16V", "spacing"): 0.020,
                 ("paper-test3", "RS-E32", "ev"): 0.090,
                 ("paper-test2", "RS-E32-AD", "ev"): 0.124,
                 ("paper-test3", "RS-E32-AD", "ev"): 0.090,
                 ("paper-test3", "G16VV", "train"): 0.024,
                 ("paper-test3", "G16VV", "spacing"): 0.016}

# Evaluation fields copied into the table rows: the paper's metric columns, gijax's beside them.
ROW_METRICS = ("mae", "rmse", "ssim", "bad_0.1", "bad_0.4", "metric_set", "mae_gijax",
               "rmse_gijax", "ssim_gijax", "bad_0.1_gijax", "bad_0.4_gijax", "pixels_gijax",
               "coverage", "time_ms", "time_ms_mean", "peak_mb", "samples", "pixels",
               "candidates", "reused", "eval_seconds")


@dataclasses.dataclass(frozen=True)
class Scale:
    """Sizes of one experiment scale.

    ``image_scale`` scales the 1024 px fisheye images; ``pano_hw`` is the label panorama
    (height, width), equal to the networks' output. ``tiny`` shrinks every network further
    (ModelConfig overrides, see :func:`model_overrides`). ``rtss_overrides`` replace RTSS preset
    fields (all scales match at the cameras' image width up to the paper's 512 px).
    """

    name: str
    image_scale: float
    pano_hw: tuple
    train_samples: int
    val_samples: int
    test_samples: dict
    models: tuple
    preset_suffix: str
    tiny: bool
    steps: int
    batch: int
    lr: float
    val_every: int
    ckpt_every: int
    rtss_same: tuple
    rtss_new: tuple
    progress: bool
    summary: str


SCALES = {
    "smoke": Scale(
        name="smoke", image_scale=0.125, pano_hw=(16, 64), train_samples=4, val_samples=2,
        test_samples={"paper-test1": 2, "paper-test2": 2, "paper-test3": 2, "paper-train-1m": 2},
        models=("G16VV",), preset_suffix="-cpu", tiny=True, steps=3, batch=2, lr=2e-4,
        val_every=0, ckpt_every=0, rtss_same=("RS-E16",), rtss_new=("RS-E16",), progress=False,
        summary=("pipeline check only, not evidence: 128 px images, 4 training, 2 validation "
                 "and 2 test samples per rig, G16VV shrunk to 66 thousand parameters and "
                 "trained 3 steps, RTSS as RS-E16 only")),
    "cpu": Scale(
        name="cpu", image_scale=0.25, pano_hw=(32, 128), train_samples=400, val_samples=24,
        test_samples={"paper-test1": 64, "paper-test2": 64, "paper-test3": 64,
                      "paper-train-1m": 64},
        models=MODELS, preset_suffix="-cpu", tiny=False, steps=2500, batch=4, lr=2e-4,
        val_every=500, ckpt_every=250,
        rtss_same=("RS-E16", "RS-G16", "RS-E32", "RS-G32", "RS-E32-AD"),
        rtss_new=("RS-E32", "RS-E32-AD"), progress=True,
        summary=("the reported figures: -cpu presets (256 px images, 32 x 128 output), 400 "
                 "training scenes, 2500 steps of batch 4 per model, 64 test scenes per rig")),
    "paper": Scale(
        name="paper", image_scale=1.0, pano_hw=(160, 640), train_samples=20000, val_samples=200,
        test_samples={"paper-test1": 1000, "paper-test2": 100, "paper-test3": 100,
                      "paper-train-1m": 100},
        models=MODELS, preset_suffix="", tiny=False, steps=100000, batch=16, lr=1e-4,
        val_every=5000, ckpt_every=1000,
        rtss_same=("RS-E16", "RS-G16", "RS-E32", "RS-G32", "RS-E32-AD"),
        rtss_new=("RS-E32", "RS-E32-AD"), progress=True,
        summary=("the paper's sizes (1024 px images, 160 x 640 output, batch 16, learning "
                 "rate 1e-4) for GPUs; the paper trained on 95K samples, this renders 20K")),
}


# --------------------------------------------------------------------------- provenance

def git_revision() -> str:
    """``HEAD`` commit, with ``+dirty`` when tracked files differ from it (the result files
    these scripts write themselves do not count)."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                              cwd=ROOT, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--",
                                ".", ":!experiments/results", ":!experiments/RESULTS.md"],
                               capture_output=True, text=True, cwd=ROOT, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (head or "unknown") + ("+dirty" if dirty.strip() else "")


def machine() -> dict:
    import jax

    return {"platform": platform.platform(), "processor": platform.processor() or
            platform.machine(), "python": platform.python_version(), "cpus": os.cpu_count(),
            "jax": jax.__version__, "devices": [str(d) for d in jax.devices()]}


def command_line(script: str, argv) -> str:
    return "python " + shlex.join([f"experiments/{script}", *argv])


def host_peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# --------------------------------------------------------------------------- files

def write_text_atomic(path: Path, text: str) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_json_atomic(path: Path, obj) -> None:
    write_text_atomic(path, json.dumps(obj, indent=2, allow_nan=True) + "\n")


def read_json(path: Path):
    try:
        return json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError):
        return None


def log(msg: str) -> None:
    print(msg, flush=True)


def gijax_cli(argv: list) -> None:
    """Run a ``gijax`` subcommand in this process; a non-zero exit code raises."""
    from gijax.cli import build_parser

    args = build_parser().parse_args([str(a) for a in argv])
    rc = int(args.func(args) or 0)
    if rc:
        raise RuntimeError(f"'gijax {shlex.join(map(str, argv))}' exited with {rc}")


# --------------------------------------------------------------------------- data

def render_argv(scale: Scale, rig: str, samples: int, seed: int, out: Path) -> list:
    h, w = scale.pano_hw
    return ["render", "--rig", rig, "--samples", samples, "--out", out, "--seed", seed,
            "--scale", scale.image_scale, "--pano", f"{w}x{h}", "--style", DATA_STYLE]


def ensure_dataset(work: Path, scale: Scale, role: str) -> dict:
    """Render (or resume, or reuse) one dataset of the work folder; returns its record.

    ``role`` is 'train', 'val' or a test rig name.
    """
    rig = "paper-train" if role in ("train", "val") else role
    samples = {"train": scale.train_samples, "val": scale.val_samples}.get(role)
    if samples is None:
        samples = scale.test_samples[role]
    out = work / "data" / role
    argv = render_argv(scale, rig, samples, DATA_SEEDS[role], out)
    t0 = time.perf_counter()
    gijax_cli(argv)
    return {"role": role, "rig": rig, "path": str(out), "samples": samples,
            "seed": DATA_SEEDS[role], "style": DATA_STYLE, "command": "gijax " + shlex.join(
                map(str, argv)), "seconds": time.perf_counter() - t0}


def dataset_seeds(path: Path) -> list:
    """The render seeds recorded for the samples of a dataset folder."""
    from gijax.data import DatasetReader
    from gijax.data.format import read_file_list

    reader = DatasetReader(path, verify="none")
    return [int(row["seed"]) for t in reader.manifest["trajectories"]
            for row in read_file_list(reader.root / t["file_list"], reader.names)
            if row.get("seed")]


def check_held_out(work: Path, tests: list) -> dict:
    """Sample seeds shared between the training/validation data and each test set (must be 0)."""
    seen = set(dataset_seeds(work / "data" / "train"))
    if (work / "data" / "val").exists():
        seen |= set(dataset_seeds(work / "data" / "val"))
    overlap = {t: len(seen & set(dataset_seeds(work / "data" / t))) for t in tests}
    bad = {t: n for t, n in overlap.items() if n}
    if bad:
        raise ValueError(f"test data shares scene seeds with the training data: {bad}")
    return overlap


def style_counts(path: Path) -> dict:
    """How many samples of a 'mixed' dataset are indoor and outdoor scenes."""
    from gijax.render.render import choose_style

    counts = {"indoor": 0, "outdoor": 0}
    for s in dataset_seeds(path):
        counts[choose_style(s, DATA_STYLE)] += 1
    return counts


# --------------------------------------------------------------------------- training

def preset_name(scale: Scale, model: str) -> str:
    return model + scale.preset_suffix


def model_overrides(scale: Scale, model: str) -> dict:
    """ModelConfig overrides of a scale (empty except at the smoke scale)."""
    if not scale.tiny:
        return {}
    from gijax.nn.presets import get_preset

    base = get_preset(preset_name(scale, model))
    channels = 4
    h, w = scale.pano_hw
    return {"feature_channels": channels, "feature_blocks": [1, 1], "unet_base": 4,
            "unet_in": channels * base.num_cameras if base.cost_volume == "concat" else channels,
            "surrogate_hw": [2 * h, 2 * w], "cost_hw": [h // 2, w // 2], "output_hw": [h, w],
            "image_scale": scale.image_scale}


def train_argv(work: Path, scale: Scale, model: str, seed: int) -> list:
    preset = preset_name(scale, model)
    argv = ["train", "--preset", preset, "--data", work / "data" / "train",
            "--out", work / "runs" / preset, "--steps", scale.steps, "--batch", scale.batch,
            "--lr", scale.lr, "--val-every", scale.val_every, "--ckpt-every", scale.ckpt_every,
            "--seed", seed, "--workers", 1 if scale.tiny else 2]
    if scale.val_samples:
        argv += ["--val", work / "data" / "val"]
    for k, v in model_overrides(scale, model).items():
        argv += ["--override", f"{k}={json.dumps(v, separators=(',', ':'))}"]
    if not scale.progress:
        argv.append("--no-progress")
    return argv


def last_logged_step(run_dir: Path) -> int:
    path = run_dir / "metrics.jsonl"
    step = 0
    if path.is_file():
        for line in path.read_text().splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue            # a line cut by an interruption
            if "loss" in rec:
                step = max(step, int(rec["step"]))
    return step


def last_validation(run_dir: Path) -> Optional[dict]:
    path = run_dir / "metrics.jsonl"
    out = None
    if path.is_file():
        for line in path.read_text().splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            if rec.get("split") == "val":
                out = rec
    return out


def ensure_trained(work: Path, scale: Scale, model: str, seed: int) -> dict:
    """Train one model to ``scale.steps`` (resuming), or reuse a finished run; its record."""
    preset = preset_name(scale, model)
    run_dir = work / "runs" / preset
    done_file = work / "runs" / f"{preset}.done.json"
    argv = train_argv(work, scale, model, seed)
    command = "gijax " + shlex.join(map(str, argv))
    done = read_json(done_file)
    if done and done.get("command") == command and done.get("steps") == scale.steps:
        log(f"  {preset}: reusing the finished run {run_dir}")
        return {**done, "reused": True}
    start = last_logged_step(run_dir)
    log(f"  {preset}: training {scale.steps} steps" +
        (f" (resuming after step {start})" if start else "") + f" -> {run_dir}")
    t0 = time.perf_counter()
    gijax_cli(argv)
    seconds = time.perf_counter() - t0
    record = {"model": model, "preset": preset, "run": str(run_dir), "command": command,
              "steps": scale.steps, "resumed_from_step": start, "train_seconds": seconds,
              "seconds_per_step": seconds / max(scale.steps - start, 1),
              "validation": last_validation(run_dir), "finished_unix": time.time()}
    write_json_atomic(done_file, record)
    return {**record, "reused": False}


# --------------------------------------------------------------------------- evaluation

def xla_peak_mb(compiled) -> Optional[float]:
    """Peak memory of one call of a compiled function (arguments, outputs, temporaries), MB,
    from XLA's buffer assignment (None where the backend does not report it)."""
    try:
        m = compiled.memory_analysis()
    except (AttributeError, NotImplementedError, RuntimeError):
        return None
    if m is None:
        return None
    peak = getattr(m, "peak_memory_in_bytes", 0) or 0
    if not peak:
        peak = (m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes
                - m.alias_size_in_bytes)
    return peak / 2 ** 20


_COMPILED: dict = {}


def compile_once(tag, args: tuple, build: Callable):
    """A compiled executable per (tag, argument structure, shapes and dtypes), built once per
    process: another rig with the same camera count, or another candidate list, reuses it."""
    import jax

    leaves, treedef = jax.tree.flatten(args)
    key = (tag, treedef, tuple((tuple(x.shape), str(x.dtype)) for x in leaves))
    if key not in _COMPILED:
        _COMPILED[key] = build()
    return _COMPILED[key]


@dataclasses.dataclass
class Predictor:
    """``fn(images uint8 (N,h,w,3), masks (N,h,w)) -> (inv_distance (H,W), estimated (H,W))``
    plus the candidates (D,) metres it uses and the XLA peak memory of one call (MB)."""

    fn: Callable
    candidates: np.ndarray
    peak_mb: Optional[float]


def net_predictor(run_dir: Path, rig, candidates_spec: str) -> Predictor:
    """A trained network (best validated checkpoint) on raw fisheye images of ``rig``.

    The timed call includes the resampling to surrogate images, as the classical baseline's
    includes its matching views. ``candidates_spec`` is ``gijax eval``'s ``--candidates``.
    """
    import jax
    import jax.numpy as jnp
    from flax import nnx

    from gijax.cli.cmd_eval import choose_candidates
    from gijax.model import forward as model_forward, make_grids
    from gijax.sweep.surrogate import as_float_image
    from gijax.train.trainer import load_for_inference, model_rig

    model, mc, train_cand = load_for_inference(run_dir, "best")
    if mc.cost_volume == "concat" and rig.num_cameras != mc.num_cameras:
        raise ValueError(f"{mc.name} concatenates exactly {mc.num_cameras} cameras; the rig has "
                         f"{rig.num_cameras}")
    cand = choose_candidates(candidates_spec, np.asarray(train_cand), mc, rig)
    graphdef, state = nnx.split(model)
    mrig = model_rig(rig)

    def forward(state, images, masks, rig, cand):
        out = model_forward(nnx.merge(graphdef, state), as_float_image(images)[None],
                            masks[None], make_grids(rig, cand, mc))
        return out["inv_distance"][0]

    cam = rig.cameras[0]
    n = rig.num_cameras
    images = jnp.zeros((n, cam.height, cam.width, 3), jnp.uint8)
    masks = jnp.ones((n, cam.height, cam.width), jnp.float32)
    jcand = jnp.asarray(cand, jnp.float32)
    args = (state, images, masks, mrig, jcand)
    compiled = compile_once(("net", graphdef, mc), args,
                            lambda: jax.jit(forward).lower(*args).compile())

    def fn(images, masks):
        inv = compiled(state, jnp.asarray(images), jnp.asarray(masks, jnp.float32), mrig, jcand)
        inv = jax.block_until_ready(inv)
        return inv, jnp.ones(inv.shape, bool)

    return Predictor(fn, cand, xla_peak_mb(compiled))


def rtss_predictor(rig, preset: str, pano_hw: tuple) -> Predictor:
    """The classical RTSS preset on raw fisheye images (EV, or GI computed for ``rig``)."""
    import jax
    import jax.numpy as jnp

    from gijax.baseline.rtss import _rtss, get_rtss_preset, preset_candidates
    from gijax.geometry.panorama import Panorama

    config = get_rtss_preset(preset)
    config = config.replace(match_size=min(config.match_size, min(c.width for c in rig.cameras)))
    cand = np.asarray(preset_candidates(rig, config), np.float64)
    pano = Panorama.hemisphere(*pano_hw)
    cam = rig.cameras[0]
    n = rig.num_cameras
    images = jnp.zeros((n, cam.height, cam.width, 3), jnp.float32)
    masks = jnp.ones((n, cam.height, cam.width), jnp.float32)
    jcand = jnp.asarray(cand, jnp.float32)
    # The same compiled function rtss_predict runs, lowered here to read its memory analysis.
    compiled = compile_once(("rtss", config, pano), (rig, images, masks, jcand),
                            lambda: _rtss.lower(rig, images, masks, jcand, pano=pano,
                                                config=config).compile())

    def fn(images, masks):
        out = compiled(rig, jnp.asarray(images, jnp.float32) / 255.0,
                       jnp.asarray(masks, jnp.float32), jcand)
        out = jax.block_until_ready(out)
        return out["inv_distance"], out["valid"]

    return Predictor(fn, cand, xla_peak_mb(compiled))


def evaluate(reader, predictor: Predictor) -> tuple[dict, np.ndarray]:
    """Metrics of ``predictor`` over every sample of ``reader`` (one sample per call).

    Returns (metrics, the first sample's inverse distance (H, W), NaN where not estimated).
    ``mae``, ``rmse``, ``ssim``, ``bad_0.1``, ``bad_0.4`` follow the paper's definitions; the
    same names with a ``_gijax`` suffix follow gijax's (see the module docstring).
    ``time_ms`` is the median wall time of one call (the predictor is compiled beforehand, so
    no call includes compilation); ``coverage`` is the share of labelled pixels with an
    estimate.
    """
    import jax.numpy as jnp

    from gijax.data.loader import label_valid
    from gijax.train.metrics import METRIC_SETS, batch_sums, summarize

    cand = jnp.asarray(predictor.candidates, jnp.float32)
    far = 1.0 / float(predictor.candidates[-1])
    parts = {m: [] for m in METRIC_SETS}
    times, covered, labelled, first = [], 0.0, 0.0, None
    for i in range(len(reader)):
        s = reader[i]
        t0 = time.perf_counter()
        inv, est = predictor.fn(s["images"], s["masks"])
        times.append(time.perf_counter() - t0)
        inv, est = np.asarray(inv, np.float32), np.asarray(est, bool) & np.isfinite(np.asarray(inv))
        dist = np.asarray(s["pano_distance"], np.float32)
        if inv.shape != dist.shape:
            raise ValueError(f"prediction {inv.shape} and label {dist.shape} panoramas differ "
                             f"({reader.root} sample {i})")
        valid = label_valid(dist)
        covered += float(np.sum(valid & est))
        labelled += float(np.sum(valid))
        filled = np.where(est, inv, far).astype(np.float32)
        for m in METRIC_SETS:
            sums = batch_sums(jnp.asarray(filled[None]), jnp.asarray(dist[None]),
                              jnp.asarray((valid & est)[None]), cand, metric_set=m)
            parts[m].append({k: np.asarray(v) for k, v in sums.items()})
        if first is None:
            first = np.where(est, inv, np.nan)
    if not times:
        raise ValueError(f"{reader.root} has no samples to evaluate")
    joined = {m: summarize({k: np.concatenate([p[k] for p in ps]) for k in ps[0]}, m)
              for m, ps in parts.items()}
    metrics = {**joined["paper"], "metric_set": "paper",
               **{f"{k}_gijax": v for k, v in joined["gijax"].items()
                  if k not in ("samples",)}}
    metrics["coverage"] = covered / max(labelled, 1.0)
    metrics["time_ms"] = 1000.0 * float(np.median(times))
    metrics["time_ms_mean"] = 1000.0 * float(np.mean(times))
    return metrics, first


def eval_key(**fields) -> str:
    text = json.dumps(fields, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def cached_evaluation(work: Path, key_fields: dict, make_predictor: Callable, data: Path) -> dict:
    """Evaluate once; later calls with the same key return the stored result and prediction."""
    from gijax.data import DatasetReader

    # Cached results computed under other metric definitions must not be reused.
    key_fields = {**key_fields, "metrics": METRICS_VERSION}
    key = eval_key(**key_fields)
    path = work / "evals" / f"{key}.json"
    pred_path = work / "evals" / f"{key}.first.npy"
    stored = read_json(path)
    if stored and stored.get("key") == key_fields and pred_path.is_file():
        return {**stored, "first_prediction": np.load(pred_path), "reused": True}
    reader = DatasetReader(data)
    t0 = time.perf_counter()
    predictor = make_predictor(reader.rig)
    compile_s = time.perf_counter() - t0
    metrics, first = evaluate(reader, predictor)
    result = {"key": key_fields, **metrics, "peak_mb": predictor.peak_mb,
              "candidates": [float(c) for c in predictor.candidates],
              "compile_seconds": compile_s, "eval_seconds": time.perf_counter() - t0}
    pred_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = pred_path.with_name(f".{pred_path.name}.tmp{os.getpid()}.npy")
    np.save(tmp, first)
    os.replace(tmp, pred_path)
    write_json_atomic(path, result)
    return {**result, "first_prediction": first, "reused": False}


# --------------------------------------------------------------------------- tables

def fmt(v, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def markdown_table(header: list, rows: list) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def provenance(script: str, argv, scale: Scale, seed: int, work: Path, started: float,
               durations: dict, data: list) -> dict:
    return {"command": command_line(script, argv), "scale": scale.name,
            "scale_summary": scale.summary, "seed": seed, "data_seeds": DATA_SEEDS,
            "data_style": DATA_STYLE, "datasets": data, "work": str(work),
            "git_revision": git_revision(), "machine": machine(),
            "started_unix": started, "finished_unix": time.time(),
            "durations_s": {**durations, "total": time.time() - started},
            "host_peak_rss_mb": host_peak_rss_mb()}


def provenance_markdown(prov: dict) -> str:
    m = prov["machine"]
    dur = ", ".join(f"{k} {v:.0f} s" for k, v in prov["durations_s"].items())
    data = "; ".join(f"{d['role']}: {d['rig']} x {d['samples']} (seed {d['seed']})"
                     for d in prov["datasets"])
    return "\n".join([
        f"- command: `{prov['command']}`",
        f"- scale: {prov['scale']} ({prov['scale_summary']})",
        f"- training seed: {prov['seed']}; data ({prov['data_style']} scenes): {data}",
        f"- git revision: {prov['git_revision']}",
        f"- machine: {m['platform']}, {m['cpus']} CPUs, jax {m['jax']}, devices "
        f"{', '.join(m['devices'])}",
        f"- durations: {dur}",
    ])


def save_table(out_stem: Path, title: str, markdown_body: str, doc: dict) -> None:
    """``<stem>.md`` and ``<stem>.json`` (written atomically)."""
    write_json_atomic(out_stem.with_suffix(".json"), doc)
    write_text_atomic(out_stem.with_suffix(".md"), f"# {title}\n\n{markdown_body}\n")


def update_results_section(results_md: Path, section: str, body: str) -> None:
    """Replace the text between ``<!-- section:begin -->`` and ``<!-- section:end -->``."""
    text = results_md.read_text()
    begin, end = f"<!-- {section}:begin -->", f"<!-- {section}:end -->"
    if begin not in text or end not in text:
        raise ValueError(f"{results_md} has no '{begin}' ... '{end}' markers")
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    write_text_atomic(results_md, f"{head}{begin}\n{body.strip()}\n{end}{tail}")


# --------------------------------------------------------------------------- figures

def save_figure(path: Path, sample: dict, panels: list, title: str) -> None:
    """Input fisheyes, ground-truth inverse distance, then one row per method: prediction and
    absolute error (1/m). ``panels`` is a list of (label, inverse distance (H, W))."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gijax.data.loader import label_valid

    dist = np.asarray(sample["pano_distance"], np.float64)
    valid = label_valid(dist)
    # The label as the metrics see it: inverse distance clamped to the 0.5-100 m range.
    gt = np.where(valid, np.clip(1.0 / np.maximum(dist, 1e-6), 0.01, 2.0), np.nan)
    vmax = float(np.nanpercentile(gt, 99)) if np.any(valid) else 1.0
    vmax = max(vmax, 0.05)
    images = sample["images"]
    ncam = len(images)
    rows = 2 + len(panels)
    fig = plt.figure(figsize=(10, 1.3 * rows + 2.2))
    grid = fig.add_gridspec(rows, max(ncam, 2), height_ratios=[2.2] + [1.0] * (rows - 1))
    for c in range(ncam):
        ax = fig.add_subplot(grid[0, c])
        ax.imshow(images[c])
        ax.set_title(f"camera {c}", fontsize=8)
        ax.axis("off")
    ax = fig.add_subplot(grid[1, :])
    im = ax.imshow(gt, cmap="turbo", vmin=0.0, vmax=vmax, aspect="auto")
    ax.set_title("ground truth inverse distance (1/m)", fontsize=8)
    ax.axis("off")
    fig.colorbar(im, ax=ax, fraction=0.02, pad=0.01)
    half = max(ncam, 2) // 2
    for r, (label, inv) in enumerate(panels):
        inv = np.asarray(inv, np.float64)
        err = np.where(valid, np.abs(inv - gt), np.nan)
        ax = fig.add_subplot(grid[2 + r, :half])
        ax.imshow(inv, cmap="turbo", vmin=0.0, vmax=vmax, aspect="auto")
        ax.set_title(f"{label}: prediction", fontsize=7)
        ax.axis("off")
        ax = fig.add_subplot(grid[2 + r, half:])
        im = ax.imshow(err, cmap="magma", vmin=0.0, vmax=0.25 * vmax, aspect="auto")
        ax.set_title(f"{label}: |error|, MAE {np.nanmean(err):.4f} 1/m", fontsize=7)
        ax.axis("off")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, path)


# --------------------------------------------------------------------------- arguments

def parse_script_args(doc: str, name: str, argv: list):
    """The command line shared by the table scripts -> (args, scale, work, out, results)."""
    import argparse

    parser = argparse.ArgumentParser(description=doc.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n".join(doc.splitlines()[2:]))
    add_common_arguments(parser, name)
    args = parser.parse_args(argv)
    return (args, SCALES[args.scale], *resolve_paths(args, name))


def add_common_arguments(parser, default_name: str) -> None:
    parser.add_argument("--scale", choices=list(SCALES), default="smoke",
                        help="smoke: pipeline check (about a minute); cpu: the reported figures "
                             "(hours on 2 cores, resumable); paper: the paper's sizes (GPUs)")
    parser.add_argument("--work", default=None,
                        help="shared work folder for data, runs and cached evaluations "
                             "(default experiments/out/work_<scale>)")
    parser.add_argument("--out", default=None,
                        help=f"output stem (default experiments/results/{default_name}_cpu for "
                             f"--scale cpu, else experiments/out/{default_name}_<scale>)")
    parser.add_argument("--seed", type=int, default=0, help="training seed (initialisation "
                                                            "and data order)")
    parser.add_argument("--results", default=None,
                        help="Markdown file whose section to update (default "
                             "experiments/RESULTS.md for --scale cpu, none otherwise); "
                             "'none' disables")


def resolve_paths(args, name: str) -> tuple[Path, Path, Optional[Path]]:
    work = Path(args.work) if args.work else EXPERIMENTS / "out" / f"work_{args.scale}"
    if args.out:
        out = Path(args.out)
    elif args.scale == "cpu":
        out = EXPERIMENTS / "results" / f"{name}_cpu"
    else:
        out = EXPERIMENTS / "out" / f"{name}_{args.scale}"
    if args.results == "none":
        results = None
    elif args.results:
        results = Path(args.results)
    else:
        results = EXPERIMENTS / "RESULTS.md" if args.scale == "cpu" else None
    return work, out, results


# --------------------------------------------------------------------------- claims

def _claim(name: str, status: str, detail: str, numbers: dict) -> dict:
    return {"claim": name, "status": status, "detail": detail, "numbers": numbers}


def claim_gi_at_least_ev(rows: list, small: str = "G8", even: str = "E8") -> dict:
    """(a) the GI model is at least as good (MAE) as its EV twin on the same layout."""
    name = f"(a) {small} at least as good as {even} (MAE, same layout)"
    by = {r["model"]: r for r in rows if r.get("status") == "ok"}
    if small not in by or even not in by:
        return _claim(name, "N/A", f"needs rows {even} and {small}; this scale has "
                                   f"{sorted(by)}", {})
    g, e = by[small]["mae"], by[even]["mae"]
    status = "PASS" if g <= e else "FAIL"
    return _claim(name, status, f"{small} MAE {g:.4f} vs {even} MAE {e:.4f} 1/m "
                                f"({100 * (e - g) / e:+.1f} % in {small}'s favour)",
                  {small: g, even: e})


def claim_learned_beats_classical(rows: list, factor: float = CLEAR_FACTOR,
                                  group: Optional[Callable] = None) -> dict:
    """(c) every learned row's MAE is at most ``factor`` times the best classical row's MAE
    (within each ``group(row)``, e.g. the test layout)."""
    name = (f"(c) learned models beat the classical baseline clearly (MAE <= {factor:g} x the "
            f"best RTSS MAE)")
    group = group or (lambda r: "")
    ok_rows = [r for r in rows if r.get("status") == "ok"]
    details, numbers, verdicts = [], {}, []
    for g in sorted({group(r) for r in ok_rows}):
        learned = [r for r in ok_rows if group(r) == g and r["kind"] == "learned"]
        classical = [r for r in ok_rows if group(r) == g and r["kind"] == "classical"]
        if not learned or not classical:
            continue
        best = min(classical, key=lambda r: r["mae"])
        worst = max(learned, key=lambda r: r["mae"])
        ratio = worst["mae"] / best["mae"]
        verdicts.append(ratio <= factor)
        where = f"{g}: " if g else ""
        details.append(f"{where}worst learned {row_label(worst)} MAE {worst['mae']:.4f} vs best "
                       f"classical {row_label(best)} MAE {best['mae']:.4f} 1/m (ratio "
                       f"{ratio:.2f})")
        numbers[g or "all"] = {"worst_learned": worst["mae"], "best_classical": best["mae"],
                               "ratio": ratio}
    if not verdicts:
        return _claim(name, "N/A", "needs learned and classical rows on the same data", {})
    return _claim(name, "PASS" if all(verdicts) else "FAIL", "; ".join(details), numbers)


RECOMPUTED_NAMES = {"spacing": "the paper's recomputed list (closed-form GI at the rig's camera "
                               "spacing)",
                    "rig": "gijax's rig-aware GI"}


def claim_recomputed_candidates(rows: list, in_scope: Optional[Callable] = None,
                                new: str = "spacing") -> dict:
    """(b) candidates recomputed for the new rig lower the MAE of every model in scope vs its
    training list. ``in_scope(row)`` (default: all) selects the rows the verdict rests on (the
    paper's Table II has the 16-candidate models); the others are reported beside it. ``new``
    is the recomputed list's ``eval_candidates``: 'spacing' (the paper's list, the claim) or
    'rig' (gijax's rig-aware extension, checked beside it)."""
    name = ("(b) the paper's recomputed candidates (closed-form GI at the new camera spacing) "
            "reduce MAE (paper: 33-45 %)" if new == "spacing"
            else f"(b, {new}) the same check with {RECOMPUTED_NAMES[new]} (gijax extension)")
    in_scope = in_scope or (lambda r: True)
    ok_rows = [r for r in rows if r.get("status") == "ok" and r["kind"] == "learned"]
    pairs, scope = {}, {}
    for r in ok_rows:
        pairs.setdefault((r["layout"], r["model"]), {})[r["eval_candidates"]] = r["mae"]
        scope[(r["layout"], r["model"])] = bool(in_scope(r))
    details, extra, numbers, verdicts = [], [], {}, []
    for (layout, model), v in sorted(pairs.items()):
        if "train" not in v or new not in v:
            continue
        cut = 100.0 * (v["train"] - v[new]) / v["train"]
        text = (f"{model} on {layout}: {v['train']:.4f} -> {v[new]:.4f} 1/m "
                f"({cut:+.1f} % reduction)")
        numbers[f"{layout}/{model}"] = {"train": v["train"], new: v[new],
                                        "reduction_percent": cut,
                                        "in_scope": scope[(layout, model)]}
        if scope[(layout, model)]:
            verdicts.append(v[new] < v["train"])
            details.append(text)
        else:
            extra.append(text)
    if not verdicts:
        return _claim(name, "N/A", "needs models evaluated with both candidate lists", numbers)
    detail = "; ".join(details)
    if extra:
        detail += "; beside the paper's scope: " + "; ".join(extra)
    return _claim(name, "PASS" if all(verdicts) else "FAIL", detail, numbers)


def row_label(row: dict) -> str:
    if row.get("eval_candidates") and row["kind"] == "learned":
        short = {"spacing": "new", "rig": "rig-aware", "train": "train"}.get(
            row["eval_candidates"], row["eval_candidates"])
        return f"{row['model']}/{short}"
    return row["model"]


def print_claims(claims: list, scale: Scale) -> None:
    note = " (smoke scale: checks the pipeline, not the paper's claims)" if scale.tiny else ""
    log(f"claims{note}:")
    for c in claims:
        log(f"  {c['status']:<4} {c['claim']}: {c['detail']}")


def claims_markdown(claims: list, scale: Scale) -> str:
    lines = []
    if scale.tiny:
        lines.append("Smoke scale: these verdicts check the pipeline, not the paper's claims.\n")
    lines += [f"- **{c['status']}** {c['claim']}: {c['detail']}" for c in claims]
    return "\n".join(lines)
