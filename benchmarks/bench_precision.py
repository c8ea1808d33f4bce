"""Accuracy of the reduced-precision exports: fp32, the fp16 precision plan, a naive all-fp16
conversion of the same graph and the int8 export, run in onnxruntime (CPU) on rendered scenes.

The model is exported fp32 (rig baked in); the plan and the naive conversion are applied to
copies of that graph (:mod:`gijax.export.precision`); the int8 file is ``export_onnx(...,
precision='int8')`` calibrated on ``--calibration`` rendered scenes (seeds 1000...), disjoint
from the evaluated scenes (seeds 2000...). Each file runs the same rendered
scenes of the paper's training rig; the table gives the MAE in inverse distance (1/m, gijax's
metric set, against the rendered panorama distance) per file, and the largest, 99th-percentile
and mean difference of the inverse distance from the fp32 file.

``--size paper`` takes a paper-size network instead (``--preset``, default G16V-released:
1024 x 1024 fisheyes, 512 x 2048 surrogates, 160 x 640 output), where a fisheye pixel
coordinate in float16 is resolved to 0.5 px (0.25 px below 512) and the plan's float32 islands
are meant to matter. There are no trained paper-size weights here: the network has random
weights, or a state dict of the authors' released network (``--release-weights``, mapped by
:mod:`gijax.nn.release_weights`); the MAE of an untrained network says nothing, so the table
gives the differences from the fp32 file only (int8 left out unless ``--int8``: at paper size
its calibration records every island convolution's tensors: G16VV with 2 scenes and 2
calibration scenes took 2.5 minutes and a 9 GB peak on 2 cores). onnxruntime keeps float16 tensors in float16 between
nodes on the CPU (its fp16 kernels may compute in float32 inside), so the rounding of the
sampling coordinates and of every stored intermediate is what the figures show.

  python benchmarks/bench_precision.py                       # bundled G16VV-cpu, 4 scenes
  python benchmarks/bench_precision.py --ckpt G16VV-cpu --scenes 8 --json out.json
  python benchmarks/bench_precision.py --size paper --scenes 2 \
      --release-weights ../shared/fixtures/release/g16v_released.npz
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
    ap.add_argument("--size", choices=("cpu", "paper"), default="cpu",
                    help="cpu: a trained model (--ckpt), MAE against the rendered distance; "
                         "paper: a paper-size --preset, differences from fp32 only")
    ap.add_argument("--ckpt", default="G16VV-cpu", help="bundled model name or run folder")
    ap.add_argument("--preset", default="G16V-released",
                    help="--size paper: the network (random weights unless --release-weights)")
    ap.add_argument("--release-weights", metavar="FILE",
                    help="--size paper: a state dict of the authors' released network (.npz, "
                         ".ckpt, .pth) mapped onto --preset")
    ap.add_argument("--int8", action=argparse.BooleanOptionalAction, default=None,
                    help="include the int8 file (default: at CPU size only)")
    ap.add_argument("--rig", default="paper-train", metavar="NAME|FILE",
                    help="the rig of the rendered scenes: a built-in rig name or a rig file "
                         "(default: paper-train)")
    ap.add_argument("--scenes", type=int, default=4, help="rendered scenes (seeds 2000...)")
    ap.add_argument("--calibration", type=int, default=4,
                    help="int8 calibration scenes (seeds 1000...)")
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = ap.parse_args(argv)
    if args.size == "cpu" and args.release_weights:
        ap.error("--release-weights is for --size paper (at CPU size --ckpt names the model)")
    with_int8 = args.size == "cpu" if args.int8 is None else args.int8

    import onnx

    from gijax.candidates.spec import model_candidates
    from gijax.evaluate.metrics import evaluate_batch
    from gijax.export.onnx_export import OUTPUTS, export_onnx, rig_at_model_size
    from gijax.export.ort_session import make_session
    from gijax.export.precision import FLOAT, naive_fp16, plan_fp16
    from gijax.io.rigfile import load_rig
    from gijax.model import model_panorama
    from gijax.render import render_sample
    from gijax.store import load_model

    if args.size == "cpu":
        model, cfg, train_cand = load_model(args.ckpt)
        label = args.ckpt
    else:
        model, cfg, train_cand, label = paper_model(args.preset, args.release_weights)
    rig = load_rig(args.rig)
    cand, _ = model_candidates("train", rig, cfg, train=train_cand)
    run_rig, pano = rig_at_model_size(cfg, rig), model_panorama(cfg)
    probes = {}
    with tempfile.TemporaryDirectory() as tmp:
        paths = {"fp32": Path(tmp) / "fp32.onnx"}
        export_onnx(model, rig, cand, paths["fp32"])
        if args.size == "paper":
            # Untrained weights barely move the output: look inside as well.
            proto = onnx.load(str(paths["fp32"]))
            probes = probe_tensors(proto)
            add_outputs(proto, probes, FLOAT)
            onnx.save_model(proto, str(paths["fp32"]))
        for name, convert in (("plan", plan_fp16), ("naive", naive_fp16)):
            proto = onnx.load(str(paths["fp32"]))
            convert(proto)
            # The probes are outputs already: float32 in the plan, computed in float16 and
            # cast back to float32 by the naive conversion (a float32 interface).
            paths[name] = Path(tmp) / f"{name}.onnx"
            onnx.save_model(proto, str(paths[name]))
        if with_int8:
            paths["int8"] = Path(tmp) / "int8.onnx"
            export_onnx(model, rig, cand, paths["int8"], precision="int8",
                        calibration_scenes=args.calibration)
        sessions = {k: make_session(str(p)) for k, p in paths.items()}
        preds = {k: [] for k in sessions}
        probed = {k: {p: [] for p in probes} for k in sessions if k != "int8"}
        labels = []
        for i in range(args.scenes):
            s = render_sample(run_rig, 2000 + i, pano=pano)
            feed = {"images": s["images"][None].astype(np.float32) / 255.0,
                    "masks": s["masks"][None].astype(np.float32)}
            labels.append(s["pano_distance"])
            for k, sess in sessions.items():
                names = list(OUTPUTS) + (list(probes.values()) if k in probed else [])
                out = dict(zip(names, sess.run(names, feed)))
                preds[k].append(out["inv_distance"][0])
                for p, tensor in probes.items():
                    if k in probed:
                        probed[k][p].append(out[tensor].astype(np.float32))
    distance = np.stack(labels)
    valid = np.ones_like(distance)
    rows = {}
    trained = args.size == "cpu"
    ref = np.stack(preds["fp32"])
    for k, p in preds.items():
        inv = np.stack(p)
        diff = np.abs(inv - ref)
        rows[k] = {"max_abs_diff_vs_fp32": float(diff.max()),
                   "p99_abs_diff_vs_fp32": float(np.percentile(diff, 99)),
                   "mean_abs_diff_vs_fp32": float(diff.mean()),
                   "mean_rel_diff_vs_fp32": float(diff.mean() / np.abs(ref).mean())}
        if trained:
            rows[k]["mae"] = float(evaluate_batch(inv, distance, valid, cand)["mae"])
    inside = {}
    for p in probes:
        ref_p = np.stack(probed["fp32"][p])
        for k in probed:
            d = np.abs(np.stack(probed[k][p]) - ref_p)
            inside.setdefault(k, {})[p] = {"max_abs_diff": float(d.max()),
                                           "mean_abs_diff": float(d.mean()),
                                           "mean_rel_diff": float(d.mean()
                                                                  / np.abs(ref_p).mean())}
    coords = coordinate_rounding(cfg, run_rig, cand, pano) if args.size == "paper" else {}
    (h, w) = run_rig.cameras[0].height, run_rig.cameras[0].width
    print(f"{label} ({w} x {h} fisheyes, {pano.height} x {pano.width} output) on "
          f"{args.scenes} rendered scenes of {args.rig}"
          + (f", int8 calibrated on {args.calibration} others" if with_int8 else "")
          + " (onnxruntime CPU; inverse distance, 1/m)")
    head = f"{'file':6s} " + (f"{'MAE':>10s} " if trained else "")
    print(head + f"{'max |d| vs fp32':>16s} {'p99 |d| vs fp32':>16s} {'mean |d| vs fp32':>17s} "
          f"{'mean |d| / mean':>16s}")
    for k, r in rows.items():
        print(f"{k:6s} " + (f"{r['mae']:10.5f} " if trained else "")
              + f"{r['max_abs_diff_vs_fp32']:16.2e} {r['p99_abs_diff_vs_fp32']:16.2e} "
              f"{r['mean_abs_diff_vs_fp32']:17.2e} {r['mean_rel_diff_vs_fp32']:16.2e}")
    if inside:
        print("inside the network (the input of each island's first convolution), |d| vs fp32:")
        print(f"{'file':6s} " + " ".join(f"{p + ' max':>20s} {p + ' mean':>20s} "
                                         f"{p + ' mean / mean':>24s}" for p in probes))
        for k, per in inside.items():
            print(f"{k:6s} " + " ".join(
                f"{per[p]['max_abs_diff']:20.2e} {per[p]['mean_abs_diff']:20.2e} "
                f"{per[p]['mean_rel_diff']:24.2e}" for p in probes))
    for what, err in coords.items():
        print(f"float16 rounding of the baked {what}: largest {err['max_px']:.3f} px, mean "
              f"{err['mean_px']:.3f} px (coordinates up to {err['max_coordinate']:.0f} px)")
    if args.json:
        Path(args.json).write_text(json.dumps({
            "size": args.size, "model": label, "rig": args.rig, "scenes": args.scenes,
            "image_hw": [h, w], "output_hw": [pano.height, pano.width],
            "calibration": args.calibration if with_int8 else None, "rows": rows,
            "inside": inside, "probes": probes, "coordinate_rounding": coords}, indent=2))
    return 0


def probe_tensors(proto) -> dict:
    """{'surrogates': ..., 'cost volume': ...}: the names of the tensors that enter the first
    convolution of the precision plan's first and last islands (the resampled surrogate images
    and the fused cost volume), float32 in the fp32 file and in the plan, computed in float16
    by the naive conversion."""
    from gijax.export.precision import fp16_islands

    islands = fp16_islands(proto)
    if len(islands) < 2:
        raise ValueError(f"expected the plan's two islands; found {len(islands)}")
    nodes = proto.graph.node
    return {"surrogates": nodes[islands[0].first].input[0],
            "cost volume": nodes[islands[-1].first].input[0]}


def add_outputs(proto, probes: dict, elem_type: int) -> None:
    """Make the ``probes`` tensors graph outputs too."""
    from onnx import helper

    for name in probes.values():
        proto.graph.output.append(helper.make_tensor_value_info(name, elem_type, None))


def coordinate_rounding(cfg, run_rig, cand, pano) -> dict:
    """How far float16 moves the sampling coordinates baked into the file: the fisheye pixel
    of every surrogate pixel and the feature-map pixel of every sweep point (valid ones),
    in pixels."""
    from gijax.model import model_grids
    from gijax.sweep.grids import surrogate_resampling

    maps = surrogate_resampling(run_rig, cfg.surrogate_hw)
    grids = model_grids(cfg, run_rig, np.asarray(cand, np.float32), pano)
    out = {}
    for what, px, ok in (("fisheye pixel of each surrogate pixel", maps.fisheye_px,
                          maps.fisheye_ok),
                         ("feature-map pixel of each sweep point", grids.sweep_px,
                          grids.sweep_ok)):
        px = np.asarray(px, np.float32)[np.asarray(ok, bool)]
        err = np.abs(px.astype(np.float16).astype(np.float32) - px)
        out[what] = {"max_px": float(err.max()), "mean_px": float(err.mean()),
                     "max_coordinate": float(np.abs(px).max())}
    return out


def paper_model(preset: str, release_weights: str | None):
    """(model, config, candidates or None, label): ``preset`` with random weights (seed 0), or
    with the released network's state dict in ``release_weights``, in eval mode."""
    from gijax.model import create_model
    from gijax.nn.presets import get_preset

    cfg = get_preset(preset)
    model = create_model(cfg, seed=0)
    if not release_weights:
        model.eval()
        return model, cfg, None, f"{preset} (random weights)"
    from gijax.nn.release_weights import load_state_dict
    from gijax.train.import_release import read_state_dict

    stored = load_state_dict(model, read_state_dict(release_weights))
    cand = None if stored is None else np.asarray(stored, np.float64)
    return model, cfg, cand, f"{preset} (weights of {Path(release_weights).name})"


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
