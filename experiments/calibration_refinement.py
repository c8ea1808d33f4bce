"""Calibration refinement on rendered rigs: perturb a rig's calibration by known amounts, refine it
from unlabeled frames, and score it against the truth.

For every rig and seed:

1. render ``frames`` samples of the true rig (``gijax.render.render_sample``, seeds
   ``1000 * seed + k``); their labels are used only to score;
2. perturb every camera except camera 0 by a rotation of 0.5-2 degrees about a random axis and
   a translation of 1-3 cm in a random direction (drawn from ``seed``);
3. refine the perturbed rig from the images (``gijax.calibrate.refine_rig``, poses only, in
   ``rounds`` rounds: each after the first restarts from the classical baseline's distances
   matched at the calibration the previous one reached);
4. score: per camera the rotation and translation error against the truth modulo the gauge
   (camera 0 fixed, the camera 0-1 distance held: ``gauge_aligned_errors``) before and after,
   and the classical baseline's (RS-E32) inverse-distance MAE with the true, the perturbed and
   the refined calibration's poses, and with the refined poses brought into the truth's gauge
   (``align_gauge``: the scale the images cannot see, set by the true camera 0-1 distance),
   MAE over panorama pixels labelled 0.5-100 m and estimated, rendered at the scale's
   ``mae_scale`` (the size RS-E32 is made for): on the refinement's own scenes, and on
   ``held_out`` other scenes of the rig (seeds ``1000 * seed + 500 + k``) that the refinement
   never saw, with the per-scene paired difference aligned - true (bootstrap 95 % interval
   over the scenes);
5. separate information from bias: the deviation of each pose that the frames alone predict
   at the refined calibration (``gijax.calibrate.constraint.pose_constraint``, no labels), and
   the drift of one round started at the true poses and the true distances (where the
   objective's own minimum lies; a diagnostic that uses the labels).

Targets: refined poses within 0.1 degrees and 3 mm of the truth modulo the gauge; RTSS MAE with
the refined calibration in the truth's gauge within 5 % of its MAE with the true one, on the
held-out scenes (a handful of frames is too few to resolve 5 %: on three frames the refined
poses scored from -18 % to +31 % against the true ones). Modulo the gauge for both: the
perturbation moves camera 1, so the camera 0-1 distance the refinement holds is off by up to
3 cm (4 % on ``paper-train``), and every RTSS distance with it.

Writes ``<out>.md``, ``<out>.json`` and ``<out>.png`` (default
``experiments/out/calibration_refinement_<scale>``; ``experiments/results/..._cpu`` and a
section of ``experiments/RESULTS.md`` for ``--scale cpu``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.arguments import resolve_paths  # noqa: E402
from experiments.claims import paired_difference, paired_text  # noqa: E402
from experiments.provenance import command_line, revision  # noqa: E402
from experiments.reporting import (fmt, save_png, update_results_section, write_json,  # noqa: E402
                                   write_text)
from gijax.bench.machine import machine_info  # noqa: E402
from gijax.bench.report import markdown_grid  # noqa: E402

RIGS = ("paper-train", "paper-test3")
SCALES = {
    # image scale of the 1024 px rigs the refinement works at, rendered frames per rig, Adam
    # steps per round, rounds, seeds, label and RTSS panorama (H, W), refinement panorama
    # (H, W), the edge-aware smoothness weight, and the image scale RTSS's MAE is scored at
    # (the poses carry over)
    "smoke": dict(image_scale=0.125, frames=2, steps=30, rounds=2, seeds=(0,),
                  pano_hw=(16, 64), refine_hw=(16, 64), smoothness=0.02, mae_scale=0.125,
                  held_out=2),
    # 512 px: at 256 px the objective's own minimum sat 0.3 deg / 8 mm from the truth (a
    # refinement started at the true poses drifted there; measured before the images were
    # flattened, RefineConfig.flatten), at 512 px within 0.1 deg. RTSS is
    # scored at 256 px, where RS-E32 is at its best on these rigs (its 7-pixel window and 32
    # candidates are sized for it: MAE 0.11 at 256 px, 0.42 at 512 px on paper-test3).
    # Three rounds: the first round's distances were matched at the perturbed calibration,
    # and on far scenes a translation error hides in them (one round left 10-27 mm); matched
    # again at the refined poses they let the translations go (a fourth and fifth round moved
    # no camera by more than 0.4 mm more). Eight frames (--frames 8, before flattening) were
    # not better overall: they brought paper-train seed 1 inside the pose target and took both
    # paper-test3 runs out (experiments/results/calibration_refinement_cpu_8frames.md).
    "cpu": dict(image_scale=0.5, frames=3, steps=400, rounds=3, seeds=(0, 1),
                pano_hw=(40, 160), refine_hw=(48, 192), smoothness=0.002, mae_scale=0.25,
                held_out=16),
}
TARGET_DEG, TARGET_MM, TARGET_MAE = 0.1, 3.0, 0.05
SECTION = "calibration-refinement"


def perturb(rig, seed: int):
    """The rig with cameras 1.. turned by 0.5-2 deg and moved by 10-30 mm (random directions)."""
    import jax.numpy as jnp

    from gijax.geometry.rotations import axis_angle_to_matrix

    rng = np.random.default_rng(seed)
    rots = np.asarray(rig.rotations, np.float64).copy()
    trans = np.asarray(rig.translations, np.float64).copy()
    for i in range(1, rig.num_cameras):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = np.deg2rad(rng.uniform(0.5, 2.0))
        rots[i] = rots[i] @ np.asarray(axis_angle_to_matrix(jnp.asarray(axis * angle)))
        step = rng.normal(size=3)
        trans[i] += rng.uniform(0.01, 0.03) * step / np.linalg.norm(step)
    return rig.replace(rotations=jnp.asarray(rots, rig.rotations.dtype),
                       translations=jnp.asarray(trans, rig.translations.dtype))


def rtss_errors(rig, frames: list, pano) -> list:
    """RS-E32's absolute inverse-distance errors (1/m) on each frame's labelled (0.5-100 m),
    estimated pixels: one array per frame."""
    from gijax.baseline.rtss import rtss_predict_sample

    errs = []
    for s in frames:
        out = rtss_predict_sample(rig, s, "RS-E32", pano=pano)
        d = np.asarray(s["pano_distance"], np.float64)
        inv = np.asarray(out["inv_distance"], np.float64)
        ok = (d >= 0.5) & (d <= 100.0) & np.asarray(out["valid"]) & np.isfinite(inv)
        errs.append(np.abs(inv[ok] - 1.0 / d[ok]))
    return errs


def score_calibrations(scored, calibrations: dict, frames: list, pano) -> dict:
    """Per calibration name: RS-E32's MAE over the frames' pooled pixels (``mae``) and each
    frame's own MAE (``per_scene``, None for a frame without a scored pixel), with the poses
    of that calibration on the cameras of ``scored``."""
    out = {}
    for name, rig in calibrations.items():
        errs = rtss_errors(scored.replace(rotations=rig.rotations,
                                          translations=rig.translations), frames, pano)
        out[name] = {"mae": float(np.mean(np.concatenate(errs))),
                     "per_scene": [float(e.mean()) if e.size else None for e in errs]}
    return out


def run_case(name: str, seed: int, cfg: dict) -> dict:
    from gijax.calibrate import RefineConfig, align_gauge, gauge_aligned_errors, refine_rig
    from gijax.calibrate.constraint import pose_constraint
    from gijax.calibrate.refine import MAX_DISTANCE, MIN_DISTANCE, refine_panorama
    from gijax.geometry.layouts import builtin_rig
    from gijax.geometry.panorama import Panorama
    from gijax.geometry.rig import scale_rig, with_occlusion_masks
    from gijax.render import render_sample

    t0 = time.perf_counter()
    truth = with_occlusion_masks(scale_rig(builtin_rig(name), cfg["image_scale"]))
    pano = Panorama.hemisphere(*cfg["pano_hw"])
    frames = [render_sample(truth, 1000 * seed + k, pano) for k in range(cfg["frames"])]
    t_render = time.perf_counter() - t0
    start = perturb(truth, seed)
    images = np.stack([f["images"] for f in frames])
    masks = np.stack([f["masks"] for f in frames])
    t0 = time.perf_counter()
    config = RefineConfig(steps=cfg["steps"], pano_hw=tuple(cfg["refine_hw"]),
                          smoothness=cfg["smoothness"], rounds=cfg["rounds"])
    result = refine_rig(start, images, masks, config,
                        labels=[f"{name}/{1000 * seed + k}" for k in range(cfg["frames"])])
    t_refine = time.perf_counter() - t0
    # What the frames alone say about how well they fix each pose (no labels used).
    constraint = pose_constraint(result.rig, images, masks, result.inv_distance, config)
    # Where the objective's own minimum lies (a diagnostic that uses the labels): one round
    # started at the true poses with the true distances. A drift the size of the predicted
    # deviation is noise; a larger one is a bias of the objective, which more rounds or
    # frames of the same kind cannot remove.
    t0 = time.perf_counter()
    refine_pano = refine_panorama(truth, config)
    true_inv = np.stack([1.0 / np.clip(np.nan_to_num(np.asarray(
        render_sample(truth, 1000 * seed + k, refine_pano)["pano_distance"], np.float64),
        nan=MAX_DISTANCE), MIN_DISTANCE, MAX_DISTANCE) for k in range(cfg["frames"])])
    from_truth = refine_rig(truth, images, masks, config.replace(rounds=1),
                            initial_inv=true_inv, progress=False)
    drift = gauge_aligned_errors(from_truth.rig, truth)
    t_truth = time.perf_counter() - t0
    before = gauge_aligned_errors(start, truth)
    after = gauge_aligned_errors(result.rig, truth)
    t0 = time.perf_counter()
    # RTSS is scored at its own image size: the same scenes rendered there, each rig's poses
    # on the cameras of that size.
    scored = with_occlusion_masks(scale_rig(builtin_rig(name), cfg["mae_scale"]))
    mae_frames = (frames if cfg["mae_scale"] == cfg["image_scale"] else
                  [render_sample(scored, 1000 * seed + k, pano) for k in range(cfg["frames"])])
    held_frames = [render_sample(scored, 1000 * seed + 500 + k, pano)
                   for k in range(cfg["held_out"])]
    calibrations = {"true": truth, "perturbed": start, "refined": result.rig,
                    "aligned": align_gauge(result.rig, truth)[0]}
    on_frames = score_calibrations(scored, calibrations, mae_frames, pano)
    held = score_calibrations(scored, calibrations, held_frames, pano)
    mae = {k: v["mae"] for k, v in on_frames.items()}
    t_mae = time.perf_counter() - t0
    row = {"rig": name, "seed": seed, "cameras": list(truth.names),
           "start_rotation_deg": before["rotation_deg"], "start_translation_mm":
               before["translation_mm"], "final_rotation_deg": after["rotation_deg"],
           "final_translation_mm": after["translation_mm"], "gauge_scale": after["scale"],
           "mae_true": mae["true"], "mae_perturbed": mae["perturbed"],
           "mae_refined": mae["refined"], "held_out": held,
           "mae_aligned": mae["aligned"],
           "held_out_paired": paired_difference(held["aligned"]["per_scene"],
                                                held["true"]["per_scene"]),
           "loss_before": result.loss_before,
           "loss_after": result.loss_after,
           "constraint": constraint,
           "from_truth_rotation_deg": drift["rotation_deg"],
           "from_truth_translation_mm": drift["translation_mm"],
           "seconds": {"render": t_render, "refine": t_refine, "rtss_mae": t_mae,
                       "from_truth": t_truth}}
    row["meets_pose_target"] = bool(max(after["rotation_deg"]) <= TARGET_DEG
                                    and max(after["translation_mm"]) <= TARGET_MM)
    row["meets_mae_target"] = bool(held["aligned"]["mae"]
                                   <= (1 + TARGET_MAE) * held["true"]["mae"])
    print(f"{name} seed {seed}: rotation {max(before['rotation_deg']):.3f} -> "
          f"{max(after['rotation_deg']):.3f} deg, translation "
          f"{max(before['translation_mm']):.1f} -> {max(after['translation_mm']):.1f} mm, RTSS "
          f"MAE true {mae['true']:.4f} perturbed {mae['perturbed']:.4f} refined "
          f"{mae['refined']:.4f}, on {len(held_frames)} held-out scenes "
          f"{held['true']['mae']:.4f} / {held['perturbed']['mae']:.4f} / "
          f"{held['refined']['mae']:.4f}, in the truth's gauge {held['aligned']['mae']:.4f} "
          f"({t_render:.0f} + {t_refine:.0f} + {t_mae:.0f} s)",
          flush=True)
    return row


def plot(rows: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.4))
    labels, x = [], 0
    for r in rows:
        for i, cam in enumerate(r["cameras"][1:], start=1):
            for ax, key, unit in ((a, "rotation_deg", "deg"), (b, "translation_mm", "mm")):
                ax.bar(x - 0.2, r[f"start_{key}"][i], 0.4, color="tab:red",
                       label="perturbed" if x == 0 else None)
                ax.bar(x + 0.2, r[f"final_{key}"][i], 0.4, color="tab:green",
                       label="refined" if x == 0 else None)
            labels.append(f"{r['rig']}\ns{r['seed']} {cam}")
            x += 1
    for ax, title, target in ((a, "rotation error (deg)", TARGET_DEG),
                              (b, "translation error (mm, gauge-aligned)", TARGET_MM)):
        ax.axhline(target, color="k", lw=0.8, ls="--", label="target")
        ax.set_yscale("log")
        ax.set_xticks(range(x))
        ax.set_xticklabels(labels, fontsize=6, rotation=35, ha="right")
        ax.set_title(title)
        ax.legend(fontsize=7)
    fig.suptitle("pose error per camera before / after refinement (camera 0 is the gauge)")
    fig.tight_layout()
    save_png(fig, path, dpi=110)


CALIBRATIONS = ("true", "perturbed", "refined", "aligned")


def _maes(by_calibration: dict) -> str:
    return " / ".join(fmt(by_calibration[k]) for k in CALIBRATIONS)


def _predicted(cam: dict) -> str:
    if cam["sigma_translation_mm"] is None:
        return f"not at a minimum ({100 * cam['absorbed']:.0f} %)"
    return (f"{cam['sigma_rotation_deg']:.3f} / {cam['sigma_translation_mm']:.2f} "
            f"({100 * cam['absorbed']:.0f} %)")


def table(rows: list) -> str:
    """A line per camera: its pose errors and the deviations the frames predict for it
    (``gijax.calibrate.constraint.pose_constraint`` at the refined calibration: rotation,
    translation along its least constrained direction, and the share of that direction's
    photometric curvature the re-fitted distances absorb) and how far one round started at
    the truth drifts from it (the objective's own bias); on each run's first line RS-E32's
    MAE with the true / perturbed / refined poses and the refined ones in the truth's gauge,
    on the refinement's frames and on the held-out scenes, and the held-out per-scene
    difference of the gauge-aligned poses from the true ones."""
    body = []
    for r in rows:
        held = {k: v["mae"] for k, v in r["held_out"].items()}
        rel = held["aligned"] / held["true"] - 1.0
        for i, cam in enumerate(r["cameras"]):
            first = i == 0
            body.append([r["rig"], str(r["seed"]), cam,
                         f"{r['start_rotation_deg'][i]:.3f} -> {r['final_rotation_deg'][i]:.3f}",
                         f"{r['start_translation_mm'][i]:.1f} -> "
                         f"{r['final_translation_mm'][i]:.1f}",
                         _predicted(r["constraint"]["cameras"][i]) if i else "(gauge)",
                         f"{r['from_truth_rotation_deg'][i]:.3f} / "
                         f"{r['from_truth_translation_mm'][i]:.1f}",
                         _maes({k: r[f"mae_{k}"] for k in CALIBRATIONS})
                         if first else "",
                         _maes(held) if first else "",
                         f"{rel * 100:+.1f} %; {paired_text(r['held_out_paired'])}"
                         if first else ""])
    return markdown_grid(["rig", "seed", "camera", "rotation error (deg)",
                          "translation error (mm)",
                          "predicted deviation from the frames (deg / mm; distances "
                          "absorb)",
                          "drift from the truth (deg / mm)",
                          "RTSS MAE on the frames (true / perturbed / refined / in "
                          "the truth's gauge)",
                          "RTSS MAE on held-out scenes (true / perturbed / refined / in "
                          "the truth's gauge)",
                          "held-out: gauge-aligned vs true"], body)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", choices=list(SCALES), default="smoke",
                        help="smoke: pipeline check (a few minutes); cpu: the reported figures")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help="rendered frames per rig and seed that the refinement sees "
                             "(default: the scale's, 3 at --scale cpu)")
    parser.add_argument("--out", default=None, help="output stem")
    parser.add_argument("--results", default=None,
                        help="Markdown file whose section to update (default "
                             "experiments/RESULTS.md for --scale cpu); 'none' disables")
    args = parser.parse_args(argv)
    args.work = None        # nothing is shared between runs: every frame is rendered here
    cfg = dict(SCALES[args.scale])
    if args.frames is not None:
        if args.frames < 1:
            parser.error(f"--frames must be at least 1; found {args.frames}")
        cfg["frames"] = args.frames
    _, out, results = resolve_paths(args, "calibration_refinement")
    started = time.perf_counter()
    rows = [run_case(name, seed, cfg) for name in RIGS for seed in cfg["seeds"]]
    plot(rows, out.with_suffix(".png"))
    meta = {"command": command_line("calibration_refinement.py", argv or sys.argv[1:]),
            "scale": args.scale, "config": cfg, "git_revision": revision(),
            "machine": machine_info(), "seconds": time.perf_counter() - started,
            "targets": {"rotation_deg": TARGET_DEG, "translation_mm": TARGET_MM,
                        "mae_relative": TARGET_MAE}}
    write_json(out.with_suffix(".json"), {"meta": meta, "rows": rows})
    met_pose = sum(r["meets_pose_target"] for r in rows)
    met_mae = sum(r["meets_mae_target"] for r in rows)
    summary = (f"Pose target (every camera within {TARGET_DEG} deg and {TARGET_MM} mm) met in "
               f"{met_pose} of {len(rows)} runs; RTSS MAE target (refined within "
               f"{TARGET_MAE * 100:.0f} % of true on the held-out scenes, in the truth's "
               f"gauge) met in {met_mae} of {len(rows)}.")
    md = [f"# Calibration refinement ({args.scale})", "",
          f"Command `{meta['command']}`, seeds {list(cfg['seeds'])}, git "
          f"{meta['git_revision'][:12]}, {meta['machine']['platform']}, "
          f"{meta['machine']['cpu_count']} CPUs; {meta['seconds']:.0f} s in all. Images at "
          f"{cfg['image_scale']} of 1024 px, {cfg['frames']} frames per rig, {cfg['steps']} "
          f"Adam steps in each of {cfg['rounds']} rounds, refinement panorama "
          f"{cfg['refine_hw'][0]}x{cfg['refine_hw'][1]}, "
          f"smoothness {cfg['smoothness']}; errors modulo the gauge (camera 0 fixed, camera 0-1 "
          f"distance held); RS-E32's MAE (1/m) at {cfg['mae_scale']} of 1024 px with each "
          f"calibration's poses (and the refined ones in the truth's gauge: scaled to the "
          f"true camera 0-1 distance, which images cannot see), on the refinement's own "
          f"scenes and on {cfg['held_out']} held-out scenes of each rig and seed (the "
          f"target's yardstick).", "",
          table(rows), "", summary, ""]
    write_text(out.with_suffix(".md"), "\n".join(md))
    print("\n".join(md))
    if results is not None:
        update_results_section(results, SECTION, "\n".join(md[2:]))
    print(f"wrote {out.with_suffix('.md')}, {out.with_suffix('.json')}, {out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    raise SystemExit(main())
