"""Accuracy of the reduced-precision exports: fp32, the fp16 precision plan, a naive all-fp16
conversion of the same graph and the int8 export, run in onnxruntime (CPU) on rendered scenes.

The model is exported fp32 (rig baked in); the plan and the naive conversion are applied to
copies of that graph (:mod:`gijax.export.precision`); the int8 file is ``export_onnx(...,
precision='int8')`` calibrated on ``--calibration`` rendered scenes (seeds 1000...), disjoint
from the evaluated scenes (seeds 2000...). Each file runs the same rendered
scenes of the paper's training rig; the table gives the MAE in inverse distance (1/m, gijax's
metric set, against the rendered panorama distance) per file, and the largest and mean
difference of the inverse distance from the fp32 file.

  python benchmarks/bench_precision.py                       # bundled G16VV-cpu, 4 scenes
  python benchmarks/bench_precision.py --ckpt G16VV-cpu --scenes 8 --json out.json
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ckpt", default="G16VV-cpu", help="bundled model name or run folder")
    ap.add_argument("--rig", default="paper-train")
    ap.add_argument("--scenes", type=int, default=4, help="rendered scenes (seeds 2000...)")
    ap.add_argument("--calibration", type=int, default=4,
                    help="int8 calibration scenes (seeds 1000...)")
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = ap.parse_args(argv)

    import onnx

    from gijax.candidates.spec import resolve_candidates
    from gijax.evaluate.metrics import evaluate_batch
    from gijax.export.onnx_export import OUTPUTS, export_onnx, model_rig
    from gijax.export.ort_session import make_session
    from gijax.export.precision import naive_fp16, plan_fp16
    from gijax.io.rigfile import load_rig
    from gijax.model import model_panorama
    from gijax.render import render_sample
    from gijax.store import load_model

    model, cfg, train_cand = load_model(args.ckpt)
    rig = load_rig(args.rig)
    cand, _ = resolve_candidates("train", rig, cfg.num_candidates, cfg.d_min, cfg.d_max,
                                 train=train_cand, kind=cfg.candidates)
    run_rig, pano = model_rig(cfg, rig), model_panorama(cfg)
    with tempfile.TemporaryDirectory() as tmp:
        paths = {"fp32": Path(tmp) / "fp32.onnx"}
        export_onnx(model, rig, cand, paths["fp32"])
        for name, convert in (("plan", plan_fp16), ("naive", naive_fp16)):
            proto = onnx.load(str(paths["fp32"]))
            convert(proto)
            paths[name] = Path(tmp) / f"{name}.onnx"
            onnx.save_model(proto, str(paths[name]))
        paths["int8"] = Path(tmp) / "int8.onnx"
        export_onnx(model, rig, cand, paths["int8"], precision="int8",
                    calibration_scenes=args.calibration)
        sessions = {k: make_session(str(p)) for k, p in paths.items()}
        preds = {k: [] for k in sessions}
        labels = []
        for i in range(args.scenes):
            s = render_sample(run_rig, 2000 + i, pano=pano)
            feed = {"images": s["images"][None].astype(np.float32) / 255.0,
                    "masks": s["masks"][None].astype(np.float32)}
            labels.append(s["pano_distance"])
            for k, sess in sessions.items():
                out = dict(zip(OUTPUTS, sess.run(list(OUTPUTS), feed)))
                preds[k].append(out["inv_distance"][0])
    distance = np.stack(labels)
    valid = np.ones_like(distance)
    rows = {}
    for k, p in preds.items():
        inv = np.stack(p)
        diff = np.abs(inv - np.stack(preds["fp32"]))
        mae = evaluate_batch(inv, distance, valid, cand)["mae"]
        rows[k] = {"mae": float(mae), "max_abs_diff_vs_fp32": float(diff.max()),
                   "mean_abs_diff_vs_fp32": float(diff.mean())}
    print(f"{args.ckpt} on {args.scenes} rendered scenes of {args.rig}, int8 calibrated on "
          f"{args.calibration} others (onnxruntime CPU; inverse distance, 1/m)")
    print(f"{'file':6s} {'MAE':>10s} {'max |d| vs fp32':>16s} {'mean |d| vs fp32':>17s}")
    for k, r in rows.items():
        print(f"{k:6s} {r['mae']:10.5f} {r['max_abs_diff_vs_fp32']:16.2e} "
              f"{r['mean_abs_diff_vs_fp32']:17.2e}")
    if args.json:
        Path(args.json).write_text(json.dumps({"ckpt": args.ckpt, "rig": args.rig,
                                               "scenes": args.scenes,
                                               "calibration": args.calibration, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
