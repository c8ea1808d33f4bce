"""Evaluation of a method on a test dataset: the library's predictors of raw images
(:class:`gijax.predict.LearnedImagePredictor`, :class:`gijax.predict.RtssBatchPredictor`)
called one sample at a time with their peak memory, the metrics over every sample
(:func:`gijax.evaluate.loop.evaluate_predictions`), and the cache under ``evals/``.

Metrics (:mod:`gijax.evaluate.metrics`, inverse distance in 1/m): the columns compared with the
paper's figures (``mae``, ``rmse``, ``ssim``, ``bad_0.1``, ``bad_0.4``) use the paper's
definitions, ``gijax eval --metrics paper``: per-sample MAE / RMSE over labels inside the
candidate range (0.5-100 m; sky and nearer pixels excluded), torchmetrics' SSIM, means over
samples. gijax's own definitions (labels clamped to the range, pooled pixels, fixed-range SSIM)
are kept beside them with a ``_gijax`` suffix. The classical baseline leaves a few pixels
without an estimate: MAE and RMSE are taken over its estimated pixels (``coverage`` reports
their share) and SSIM fills the holes with the farthest candidate.

Each evaluation is stored under ``evals/<key>.json`` (with the first sample's prediction for the
figures) and reused while its key (method, training command, data, candidates, metric
definitions) is unchanged.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import time
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from experiments.reporting import read_json, write_json
from gijax.io.paths import write_bytes_atomic
from gijax.store.packs import is_pack, read_pack

# Identifies the metric definitions of cached evaluations (evals/<key>.json): the paper's
# columns plus gijax's beside them. Change it when a definition changes.
METRICS_VERSION = "paper+gijax-1"

# Evaluation fields copied into the table rows: the paper's metric columns, gijax's beside them.
ROW_METRICS = ("mae", "rmse", "ssim", "bad_0.1", "bad_0.4", "metric_set", "mae_gijax",
               "rmse_gijax", "ssim_gijax", "bad_0.1_gijax", "bad_0.4_gijax", "pixels_gijax",
               "coverage", "time_ms", "time_ms_mean", "peak_mb", "samples", "pixels",
               "candidates", "reused", "eval_seconds")


def xla_peak_mb(compiled) -> Optional[float]:
    """Peak memory of one call of a compiled function, MB: XLA's own heap-simulation peak where
    the backend reports it, else arguments + outputs + temporaries (None where XLA reports
    nothing; :func:`gijax.bench.memory.compiled_memory`)."""
    from gijax.bench.memory import MIB, compiled_memory

    mem = compiled_memory(compiled)
    if not mem:
        return None
    return mem.get("reported_peak_bytes", mem["peak_bytes"]) / MIB


_MODELS: dict = {}


def _weights_fingerprint(path: Path) -> tuple:
    """Every file of a run folder or bundle by name, size and modification time: a resumed,
    retrained or rewritten model has another fingerprint."""
    path = Path(path)
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    return tuple((str(p), st.st_size, st.st_mtime_ns) for p in files for st in [p.stat()])


def loaded_model(run_dir: Path):
    """``gijax.store.load_model(run_dir, 'best')``, read once per process for the same files:
    a script evaluates each model on several test sets and candidate lists."""
    from gijax.store import load_model

    key = (str(Path(run_dir).resolve()), _weights_fingerprint(run_dir))
    if key not in _MODELS:
        _MODELS[key] = load_model(run_dir, "best")
    return _MODELS[key]


@dataclasses.dataclass
class Predictor:
    """``fn(images uint8 (N,h,w,3), masks (N,h,w)) -> (inv_distance (H,W), estimated (H,W))``
    plus the candidates (D,) metres it uses and the XLA peak memory of one call (MB)."""

    fn: Callable
    candidates: np.ndarray
    peak_mb: Optional[float]


def weights_id(path: Path) -> str:
    """A short hash of a model's weights (a bundle's ``weights.npz``, a run's best checkpoint
    folder, a resume pack's state file by the SHA-256 its ``pack.json`` holds and checks), so a
    cached evaluation follows the weights, not the path."""
    path = Path(path)
    if is_pack(path):
        return str(read_pack(path).meta["state_sha256"])[:12]
    files = [path / "weights.npz"] if (path / "weights.npz").is_file() else sorted(
        f for f in (path / "best").rglob("*") if f.is_file())
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def model_id(path: Path) -> str:
    """A short hash of a model as it predicts: its weights (:func:`weights_id`) and its network
    configuration (``config.json``'s ``model``, which names the estimate that reads the
    weights), so a cached evaluation follows the model, not the path; the same weights read
    another way are another model."""
    path = Path(path)
    config = (read_pack(path).meta["model_config"] if is_pack(path) else
              json.loads((path / "config.json").read_text()).get("model", {}))
    h = hashlib.sha256(weights_id(path).encode())
    h.update(json.dumps(config, sort_keys=True).encode())
    return h.hexdigest()[:12]


def _one_sample(batch_predictor, example: dict) -> Predictor:
    """A library batch predictor (:mod:`gijax.predict`) called one sample at a time, with the
    XLA peak memory of its compiled call for ``example``'s shapes."""
    import jax

    def fn(images, masks):
        pred = batch_predictor({"images": np.asarray(images)[None],
                                "masks": np.asarray(masks, np.float32)[None]})
        inv, valid = jax.block_until_ready((pred.inv_distance[0], pred.valid[0]))
        return inv, valid

    peak = xla_peak_mb(batch_predictor.lower(example).compile())
    return Predictor(fn, batch_predictor.candidates, peak)


def _example(rig, dtype) -> dict:
    cam = rig.cameras[0]
    n = rig.num_cameras
    return {"images": np.zeros((1, n, cam.height, cam.width, 3), dtype),
            "masks": np.ones((1, n, cam.height, cam.width), np.float32)}


def net_predictor(run_dir: Path, rig, candidates_spec: str,
                  estimate: Optional[str] = None, mode_pick: Optional[int] = None) -> Predictor:
    """A trained network (a run folder's best validated checkpoint, or a bundle) on raw
    fisheye images of ``rig`` (:class:`gijax.predict.LearnedImagePredictor`).

    The timed call includes the resampling to surrogate images, as the classical baseline's
    includes its matching views. ``candidates_spec`` is ``gijax eval``'s ``--candidates``,
    ``estimate`` its ``--estimate`` and ``mode_pick`` the mode's pick
    (:mod:`gijax.nn.regressor`; None: the model's own).
    """
    from gijax.candidates.spec import model_candidates
    from gijax.model import with_estimate
    from gijax.predict import LearnedImagePredictor

    model, mc, train_cand = loaded_model(run_dir)
    model = with_estimate(model, estimate, mode_pick)
    mc = model.config
    cand, _ = model_candidates(candidates_spec, rig, mc, train=train_cand)
    return _one_sample(LearnedImagePredictor(model, rig, cand), _example(rig, np.uint8))


def rtss_predictor(rig, preset: str, pano_hw: tuple) -> Predictor:
    """The classical RTSS preset on raw fisheye images (EV, or GI computed for ``rig``;
    :class:`gijax.predict.RtssBatchPredictor`)."""
    from gijax.baseline.rtss import get_rtss_preset, preset_candidates
    from gijax.geometry.panorama import Panorama
    from gijax.predict import RtssBatchPredictor

    config = get_rtss_preset(preset)
    config = config.replace(match_size=min(config.match_size, min(c.width for c in rig.cameras)))
    cand = np.asarray(preset_candidates(rig, config), np.float64)
    predictor = RtssBatchPredictor(rig, cand, Panorama.hemisphere(*pano_hw), config)
    return _one_sample(predictor, _example(rig, np.float32))


def evaluate(reader, predictor: Predictor) -> tuple[dict, np.ndarray]:
    """Metrics of ``predictor`` over every sample of ``reader`` (one sample per call).

    Returns (metrics, the first sample's inverse distance (H, W), NaN where not estimated).
    ``mae``, ``rmse``, ``ssim``, ``bad_0.1``, ``bad_0.4`` follow the paper's definitions; the
    same names with a ``_gijax`` suffix follow gijax's (see the module docstring).
    ``time_ms`` is the median wall time of one call (the predictor is compiled beforehand, so
    no call includes compilation); ``coverage`` is the share of labelled pixels with an
    estimate; ``mae_per_sample`` lists each sample's paper MAE (None for a sample without a
    pixel in range), whose mean over the non-None entries is ``mae``.
    """
    from gijax.evaluate.loop import evaluate_predictions
    from gijax.evaluate.metrics import METRIC_SETS
    from gijax.evaluate.prediction import Prediction

    def samples():
        for i in range(len(reader)):
            s = reader[i]
            yield {"images": s["images"], "masks": s["masks"],
                   "distance": np.asarray(s["pano_distance"], np.float32)[None]}

    def predict(batch):
        inv, estimated = predictor.fn(batch["images"], batch["masks"])
        # A batch of one (a reshape, nothing copied inside the timing).
        return Prediction(inv_distance=inv[None], valid=estimated[None])

    result = evaluate_predictions(samples(), predict, predictor.candidates,
                                  metric_sets=METRIC_SETS, holes="unscored_far", keep=1,
                                  name=str(reader.root))
    joined = result.metrics
    metrics = {**joined["paper"], "metric_set": "paper",
               **{f"{k}_gijax": v for k, v in joined["gijax"].items()
                  if k not in ("samples",)}}
    # The paper's MAE of each sample (None without a pixel in range): paired comparisons of
    # two methods on the same scenes (experiments.claims.paired_difference).
    metrics["mae_per_sample"] = [m["mae"] if m["pixels"] > 0 else None
                                 for m in result.per_scene("paper")]
    metrics["coverage"] = result.label_coverage
    metrics["time_ms"] = 1000.0 * float(np.median(result.seconds))
    metrics["time_ms_mean"] = 1000.0 * float(np.mean(result.seconds))
    first, _ = result.examples[0]
    return metrics, np.where(first.valid & np.isfinite(first.inv_distance),
                             first.inv_distance, np.nan)


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
    # Results stored before per-sample MAEs were kept are computed again (same figures).
    if (stored and stored.get("key") == key_fields and pred_path.is_file()
            and "mae_per_sample" in stored):
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
    buf = io.BytesIO()
    np.save(buf, first)
    write_bytes_atomic(pred_path, buf.getvalue())
    write_json(path, result)
    return {**result, "first_prediction": first, "reused": False}
