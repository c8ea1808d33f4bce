"""The demo: fresh scenes on the training rig and on a new 4-camera rig, every method, one figure.

For each rig it renders a new scene with exact labels, runs the bundled learned model (with its
training candidates, with the paper's list recomputed for the rig, the closed-form GI at the
rig's camera spacing, and with gijax's rig-aware GI list) and the classical RTSS baseline,
prints MAE / RMSE / SSIM (the paper's definitions, :mod:`gijax.evaluate.metrics`, scored by
:func:`gijax.evaluate.loop.evaluate_predictions`) and time, writes
one figure (inputs, ground truth, predictions, error maps) and a coloured point cloud of the
learned prediction on the training rig.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from gijax.io.paths import save_figure_atomic, write_json_atomic

# The bundled model the demo runs unless told otherwise (gijax/assets, see 'gijax models'):
# the most accurate on the held-out rigs (README, "Bundled models").
DEFAULT_MODEL = "G32VV-cpu-zncc-mix4"
DEMO_RIGS = ("paper-train", "paper-test3")
# Scenes per rig: enough that one lucky draw does not decide the verdict, few enough that the
# demo stays under two minutes on two cores.
DEFAULT_SCENES = 3
MAX_SCENES = 64
# Scene seeds: rig k, scene j draws seed + SCENE_STRIDE * k + j.
SCENE_STRIDE = 1000


@dataclasses.dataclass
class MethodResult:
    name: str
    inv_distance: np.ndarray  # (H, W) 1/m, NaN where the method gives nothing
    seconds: float
    metrics: dict


def _evaluate(predictor, rig, sample, candidates) -> tuple[np.ndarray, float, dict, object]:
    """One method on the demo's scene: (inverse distance, NaN where it gives nothing; wall
    seconds of the call, first-call compilation included; the paper's metrics; the
    prediction)."""
    from gijax.evaluate.loop import evaluate_predictions

    made = {}

    def run(_batch):
        pred = predictor.predict(rig, sample["images"], sample["masks"])
        made["pred"] = pred
        return pred.replace(inv_distance=pred.inv_distance[None], valid=pred.valid[None])

    # Pixels a method leaves empty are scored by coverage, not by a made-up value; SSIM needs
    # a full image, so empty pixels take the method's own mean there.
    result = evaluate_predictions([{"distance": sample["pano_distance"][None]}], run,
                                  np.asarray(candidates, np.float32), holes="unscored_mean")
    pred = made["pred"]
    metrics = {**result.metrics["paper"], "coverage": result.label_coverage}
    inv = np.where(pred.valid, pred.inv_distance, np.nan)
    return inv, result.seconds[0], metrics, pred


def check_demo_arguments(out_dir, model, baseline: str, rigs, scenes: int) -> None:
    """Every argument of :func:`run_demo` checked before any work: one ``ValueError`` line
    (``FileNotFoundError`` for a model that does not exist) naming the argument."""
    from gijax.baseline.rtss import RTSS_PRESETS
    from gijax.geometry.layouts import BUILTIN_LAYOUTS
    from gijax.io.paths import check_output_dir
    from gijax.store import resolve_model_path

    if baseline not in RTSS_PRESETS:
        raise ValueError(f"--baseline {baseline!r} is not a classical baseline; expected one "
                         f"of {', '.join(sorted(RTSS_PRESETS))}")
    unknown = [r for r in rigs if r not in BUILTIN_LAYOUTS]
    if unknown:
        raise ValueError(f"demo rigs {unknown} are not built in; expected names from "
                         f"{', '.join(BUILTIN_LAYOUTS)}")
    if not 1 <= int(scenes) <= MAX_SCENES:
        raise ValueError(f"--scenes must be 1-{MAX_SCENES}; found {scenes}")
    resolve_model_path(model)
    check_output_dir(out_dir, "--out")


def run_demo(out_dir: str | os.PathLike = "gijax-demo", seed: int | None = None,
             model: str | os.PathLike = DEFAULT_MODEL, rigs=DEMO_RIGS,
             baseline: str = "RS-E32", progress: bool = True,
             scenes: int = DEFAULT_SCENES) -> dict:
    """Run the demo and write ``demo.png``, ``points.ply`` and ``demo.json`` to ``out_dir``.

    ``model`` is a training run folder, an inference bundle, a resume pack or the name of a
    bundled model.
    ``seed`` None draws fresh scenes each run (the seed used is printed and saved); each rig
    gets ``scenes`` scenes, and every method is scored on all of them: the verdict is the mean
    and the per-scene spread, not one draw. Returns ``{rig: {method: summary}}`` (see
    :func:`summarize_scenes`).
    """
    from tqdm import tqdm

    from gijax.candidates import rig_gi_candidates, spacing_gi_candidates
    from gijax.geometry.layouts import builtin_rig
    from gijax.geometry.panorama_frame import panorama_rotation
    from gijax.geometry.rig import scale_rig
    from gijax.model import model_panorama
    from gijax.predict import LearnedPredictor, RtssPredictor
    from gijax.render import render_sample
    from gijax.store import load_model
    from gijax.viz.pointcloud import panorama_points, write_ply

    check_demo_arguments(out_dir, model, baseline, rigs, scenes)
    out_dir = Path(out_dir)
    seed = int(np.random.SeedSequence().entropy % (2**31)) if seed is None else int(seed)
    net, config, train_cand = load_model(model)
    title = model_title(model, config.name)
    # The paper's rigs look along one axis: the model's own panorama, the hemisphere around it.
    pano = model_panorama(config)

    bar = tqdm(total=len(rigs) * scenes * 5, desc="demo", disable=not progress, unit="run")
    table: dict = {}
    panels = []
    cloud = None
    for k, name in enumerate(rigs):
        rig = builtin_rig(name)
        small = scale_rig(rig, config.image_scale)
        n = config.num_candidates
        # The paper's recomputed list (closed form at the rig's camera spacing), then gijax's
        # rig-aware list (docs/candidates.md); on the training rig the paper's list is the
        # training list itself.
        cands = {"training candidates": np.asarray(train_cand),
                 "paper's GI at camera spacing": np.asarray(spacing_gi_candidates(rig, n)),
                 "rig-aware GI (gijax)": np.asarray(rig_gi_candidates(rig, n))}
        per_scene: dict[str, list[MethodResult]] = {}
        samples = []
        for j in range(scenes):
            scene_seed = seed + SCENE_STRIDE * k + j
            bar.set_postfix_str(f"{name} scene {j + 1}/{scenes}: rendering")
            sample = render_sample(small, scene_seed, pano=pano)
            samples.append(sample)
            bar.update(1)
            for label, cand in cands.items():
                bar.set_postfix_str(f"{name} scene {j + 1}/{scenes}: {title} ({label})")
                learned = LearnedPredictor(net, cand, pano, colours=False)
                # The rig at its calibrated size, as every predictor takes it: the images
                # (rendered at the model's size) are then used as they are. The scaled rig
                # would read as a calibration of that size and have them scaled again.
                inv, secs, metrics, res = _evaluate(learned, rig, sample, cand)
                per_scene.setdefault(f"{title} {label}", []).append(
                    MethodResult(f"{title} {label}", inv, secs, metrics))
                if cloud is None:
                    cloud = (res, small)
                bar.update(1)
            bar.set_postfix_str(f"{name} scene {j + 1}/{scenes}: {baseline}")
            # The baseline's figures are on the model's training range, like the learned rows.
            inv, secs, metrics, _ = _evaluate(RtssPredictor(baseline, pano=pano, colours=False),
                                              rig, sample, train_cand)
            per_scene.setdefault(baseline, []).append(MethodResult(baseline, inv, secs, metrics))
            bar.update(1)
        table[name] = {m: summarize_scenes(results) for m, results in per_scene.items()}
        panels.append((name, samples[0], [results[0] for results in per_scene.values()]))
    bar.close()

    res, small = cloud
    points, keep = panorama_points(res["distance"], np.asarray(small.reference), pano,
                                   valid=res["valid"], max_distance=50.0,
                                   rotation=panorama_rotation(small))
    colours = np.clip(res["colour"][keep] * 255.0 + 0.5, 0, 255).astype(np.uint8)
    write_ply(str(out_dir / "points.ply"), points, colours)
    _figure(out_dir / "demo.png", panels, scenes)
    write_json_atomic(out_dir / "demo.json", {"seed": seed, "scenes_per_rig": scenes,
                                              "scene_seeds": {name: [seed + SCENE_STRIDE * k + j
                                                                     for j in range(scenes)]
                                                              for k, name in enumerate(rigs)},
                                              "model": str(model), "table": table})
    print(format_table(table, seed, scenes))
    print(verdict(table, baseline))
    print(model_note(model, title))
    print(f"wrote {out_dir / 'demo.png'}, {out_dir / 'points.ply'}, {out_dir / 'demo.json'}")
    return table


def summarize_scenes(results: list[MethodResult]) -> dict:
    """One method over a rig's scenes: the mean of each metric, the per-scene MAE (its spread
    is the verdict's honesty), the first call's seconds (compilation included) and the median
    of the others."""
    keys = [k for k in results[0].metrics if isinstance(results[0].metrics[k], (int, float))]
    out = {k: float(np.mean([r.metrics[k] for r in results])) for k in keys}
    out["mae_per_scene"] = [float(r.metrics["mae"]) for r in results]
    out["first_seconds"] = float(results[0].seconds)
    later = [r.seconds for r in results[1:]]
    out["seconds"] = float(np.median(later)) if later else float(results[0].seconds)
    return out


def rig_verdicts(table: dict, baseline: str) -> dict:
    """Per rig of a demo table: the learned model's best candidate list (the lowest mean MAE)
    against the baseline: ``{rig: {"method", "mae", "baseline_mae", "scenes_won", "scenes",
    "ahead"}}`` (scenes won: per-scene MAE strictly below the baseline's; ahead: mean MAE
    strictly below)."""
    out = {}
    for rig, methods in table.items():
        base = methods[baseline]
        learned = {m: v for m, v in methods.items() if m != baseline}
        best = min(learned, key=lambda m: learned[m]["mae"])
        wins = sum(a < b for a, b in zip(learned[best]["mae_per_scene"], base["mae_per_scene"]))
        out[rig] = {"method": best, "mae": learned[best]["mae"], "baseline_mae": base["mae"],
                    "scenes_won": int(wins), "scenes": len(base["mae_per_scene"]),
                    "ahead": bool(learned[best]["mae"] < base["mae"])}
    return out


def verdict(table: dict, baseline: str) -> str:
    """Per rig: the learned model's best candidate list against the baseline, by mean MAE and
    by how many scenes each wins (:func:`rig_verdicts`)."""
    lines = [f"{rig}: {'learned' if v['ahead'] else baseline} ahead on mean MAE "
             f"({v['method']} {v['mae']:.4f} vs {baseline} {v['baseline_mae']:.4f}); "
             f"the learned model wins {v['scenes_won']} of {v['scenes']} scenes"
             for rig, v in rig_verdicts(table, baseline).items()]
    return "verdict: " + "\nverdict: ".join(lines)


def model_title(model, preset: str) -> str:
    """What the demo calls the model: a bundled model by its bundle name (two bundles can share
    a preset, e.g. one with a finer cost volume), anything else by its preset."""
    from gijax.store import resolve_model_path
    from gijax.store.assets import ASSETS

    path = resolve_model_path(model)
    return path.name if path.resolve().parent == ASSETS.resolve() else preset


def model_note(model, name: str) -> str:
    """What the model was trained on, how it compared with classical stereo on held-out scenes
    and where it is expected to fail, from its provenance (bundles record them; a run folder is
    named as it is)."""
    from gijax.store import resolve_model_path
    from gijax.store.assets import held_out_comparison, limitations, trained_on
    from gijax.store.bundles import is_bundle, read_provenance

    path = resolve_model_path(model)
    if not is_bundle(path):
        return f"model {name}: the training run {path}"
    prov = read_provenance(path)
    return (f"model {name}: trained on {trained_on(prov)}\n"
            f"compared with classical stereo: {held_out_comparison(prov)}\n"
            f"expected to fail on: {limitations(prov)}")


def format_table(table: dict, seed: int, scenes: int) -> str:
    width = max([40] + [len(name) for methods in table.values() for name in methods])
    lines = [f"seed {seed}, {scenes} scene(s) per rig; inverse distance metrics in 1/m as the "
             f"paper defines them, mean over the scenes (lower MAE/RMSE is better)",
             f"{'rig':<12} {'method':<{width}} {'MAE':>7} {'min-max':>13} {'RMSE':>7} "
             f"{'SSIM':>6} {'cover':>6} {'time s':>7}"]
    for rig, methods in table.items():
        for name, m in methods.items():
            spread = f"{min(m['mae_per_scene']):.3f}-{max(m['mae_per_scene']):.3f}"
            lines.append(f"{rig:<12} {name:<{width}} {m['mae']:7.4f} {spread:>13} {m['rmse']:7.4f} "
                         f"{m['ssim']:6.3f} {m['coverage']:6.1%} {m['seconds']:7.2f}")
    lines.append("min-max: the per-scene MAE range; time: median wall seconds per scene after "
                 "the first (the first call compiles)")
    return "\n".join(lines)


def _exposed(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A camera image as a camera would show it: auto exposure (the 97th percentile of the
    valid pixels' brightness to 0.9) and display gamma, the masked-out body dimmed."""
    img = np.asarray(image, np.float32) / 255.0
    valid = np.asarray(mask) > 0
    level = np.percentile(img.max(axis=-1)[valid], 97) if valid.any() else 1.0
    img = np.clip(img * (0.9 / max(float(level), 1e-3)), 0.0, 1.0) ** (1 / 2.2)
    return img * np.where(valid, 1.0, 0.35)[..., None]


def _figure(path: Path, panels, scenes: int) -> None:
    """Write :func:`demo_figure` to ``path``."""
    import matplotlib.pyplot as plt

    fig = demo_figure(panels, scenes)
    try:
        save_figure_atomic(fig, path, dpi=80)
    finally:
        plt.close(fig)


def demo_figure(panels, scenes: int):
    """The demo's figure, left open. Per rig, its first scene: the camera images, then ground truth and every method's
    inverse distance beside its absolute error. Inverse distance shares one colour scale per
    rig, from that scene's own labels (ground truth and predictions alike); every error map of
    the figure shares one scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gijax.evaluate.labels import usable_label

    truths, errors = [], []
    for _, sample, methods in panels:
        dist = np.asarray(sample["pano_distance"], np.float64)
        truth = np.where(usable_label(dist), 1.0 / np.where(usable_label(dist), dist, 1.0),
                         np.nan)
        truths.append(truth)
        errors.append([np.abs(m.inv_distance - truth) for m in methods])
    finite = np.concatenate([e[np.isfinite(e)] for errs in errors for e in errs] or [[0.0]])
    err_max = max(float(np.percentile(finite, 95)) if finite.size else 0.0, 1e-3)

    # Pixels without a value (no estimate, no label) get a colour of their own, as the colour
    # bars say (matplotlib's default would leave them white); magma starts at black, so its
    # unscored pixels are grey.
    value_cmap = plt.get_cmap("turbo").with_extremes(bad="black")
    error_cmap = plt.get_cmap("magma").with_extremes(bad="0.6")
    height, width = np.asarray(panels[0][1]["pano_distance"]).shape
    row_h = 6.0 * height / width             # a panorama 6 inches wide at its own aspect
    heights = [2.3 + (1 + len(m)) * (row_h + 0.3) + 0.7 for _, _, m in panels]
    fig = plt.figure(figsize=(12.5, sum(heights)), layout="constrained")
    subfigs = np.atleast_1d(fig.subfigures(len(panels), 1, height_ratios=heights))
    for sub, (name, sample, methods), truth, errs in zip(subfigs, panels, truths, errors):
        vmax = float(np.nanpercentile(truth, 99)) if np.isfinite(truth).any() else 1.0
        cams = len(sample["images"])
        sub.suptitle(f"{name}: scene 1 of {scenes}", fontsize=11, fontweight="bold")
        grid = sub.add_gridspec(2 + len(methods), 2 * cams,
                                height_ratios=[2.3] + [row_h] * (1 + len(methods)))
        for c in range(cams):
            ax = sub.add_subplot(grid[0, 2 * c:2 * c + 2])
            ax.imshow(_exposed(sample["images"][c], sample["masks"][c]))
            ax.set_title(f"camera {c} (masked body dimmed)", fontsize=8)
            ax.axis("off")
        rows = [("ground truth", truth, None)] + [
            (f"{m.name}: MAE {m.metrics['mae']:.4f}", m.inv_distance, e)
            for m, e in zip(methods, errs)]
        value_axes, error_axes = [], []
        for r, (title, values, err) in enumerate(rows, start=1):
            ax = sub.add_subplot(grid[r, :cams])
            im = ax.imshow(values, cmap=value_cmap, vmin=0.0, vmax=vmax)
            ax.set_title(title, fontsize=8)
            ax.axis("off")
            value_axes.append(ax)
            if err is not None:
                ax = sub.add_subplot(grid[r, cams:])
                em = ax.imshow(err, cmap=error_cmap, vmin=0.0, vmax=err_max)
                ax.set_title("absolute error", fontsize=8)
                ax.axis("off")
                error_axes.append(ax)
        sub.colorbar(im, ax=value_axes, location="bottom", shrink=0.8, aspect=40,
                     label="inverse distance (1/m); black: no estimate or no label")
        sub.colorbar(em, ax=error_axes, location="bottom", shrink=0.8, aspect=40,
                     label="absolute error (1/m), one scale for the whole figure; grey: not scored")
    return fig
