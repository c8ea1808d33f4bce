"""``gijax candidates``: print EV / GI distance candidates for a rig and their step uniformity."""

from __future__ import annotations

import json

import numpy as np

HELP = "distance candidates (EV, closed-form GI, rig-aware GI) and their step uniformity"
DESCRIPTION = """\
Print N distance candidates (metres, ascending, d-min..d-max inclusive) and the uniformity of
their feature displacement per step on the rig: the mean displacement over panorama rays and
the cameras that see them (pixels), its min/max ratio and coefficient of variation.

kinds:
  gi         rig-aware geometry-informed: equal mean displacement steps on this rig (default)
  ev         evenly spaced in inverse distance
  gi-closed  the paper's closed form for one perpendicular baseline (--baseline, default the
             training spacing 0.3095015413531889 m, which gives the released G16/G8 lists)
  gi-spacing the closed form with the rig's camera spacing as the baseline (mean distance from
             each camera to its nearest neighbour; the released lists on paper-train)
"""


def register(subparsers) -> None:
    from gijax.cli.options import RawHelpFormatter, add_rig_option

    p = subparsers.add_parser("candidates", help=HELP, description=DESCRIPTION,
                              formatter_class=RawHelpFormatter)
    add_rig_option(p, default="paper-train")
    p.add_argument("-n", "--num", type=int, default=16, help="number of candidates (default 16)")
    p.add_argument("--kind", choices=("gi", "ev", "gi-closed", "gi-spacing"), default="gi",
                   help="candidate kind (default gi, rig-aware)")
    p.add_argument("--d-min", type=float, default=0.5, help="nearest candidate, m (default 0.5)")
    p.add_argument("--d-max", type=float, default=100.0,
                   help="farthest candidate, m (default 100)")
    p.add_argument("--baseline", type=float, default=None,
                   help="baseline for --kind gi-closed, m (default 0.3095015413531889)")
    p.add_argument("--measure", choices=("pixels", "angle"), default="pixels",
                   help="displacement measure: pixels through each camera's projection "
                        "(default) or parallax angle in radians")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.add_argument("--plot", metavar="PNG", default=None,
                   help="also write the candidate figure (displacement per step for EV and GI "
                        "at the training spacing, at 1 m and on this rig)")
    p.set_defaults(func=run)


def _load(name: str):
    from gijax.io.rigfile import load_rig

    return load_rig(name)


def run(args) -> int:
    import jax

    # The list is printed to 1e-9 m; float32 would only be good to about 1e-7 relative.
    with jax.enable_x64(True):
        return _run(args)


def _run(args) -> int:
    from gijax.candidates import (MEASURE_UNITS, candidates_for, effective_baseline,
                                  step_uniformity)
    from gijax.candidates.validation import check_count, check_range

    check_count(args.num)
    check_range(args.d_min, args.d_max)
    if args.baseline is not None and args.kind != "gi-closed":
        raise ValueError(f"--baseline is only used with --kind gi-closed; found --kind {args.kind}")
    rig = _load(args.rig)
    cands = candidates_for(args.kind, args.num, rig, args.d_min, args.d_max,
                           baseline=args.baseline, **({"measure": args.measure}
                                                      if args.kind == "gi" else {}))
    uni = step_uniformity(rig, cands, measure=args.measure)
    b_eff = effective_baseline(rig, args.num, args.d_min, args.d_max, measure=args.measure)
    c = np.asarray(cands, np.float64)
    if not np.all(np.isfinite(c)):
        raise ValueError(f"candidates for rig {args.rig!r} are not finite: {c.tolist()}")
    result = {
        "rig": args.rig,
        "kind": args.kind,
        "n": args.num,
        "d_min": args.d_min,
        "d_max": args.d_max,
        "candidates": c.tolist(),
        "inverse_candidates": (1.0 / c).tolist(),
        "unit": MEASURE_UNITS[args.measure],
        "steps": np.asarray(uni["steps"], np.float64).tolist(),
        "mean_step": float(uni["mean"]),
        "min_max_ratio": float(uni["min_max_ratio"]),
        "cv": float(uni["cv"]),
        "ray_cv": float(uni["ray_cv"]),
        "effective_baseline": float(b_eff),
    }
    if args.kind == "gi-closed":
        result["baseline"] = 0.3095015413531889 if args.baseline is None else args.baseline
    if args.kind == "gi-spacing":
        from gijax.candidates import camera_spacing

        result["baseline"] = float(camera_spacing(rig))
    if args.plot:
        from gijax.viz.candidate_plot import plot_candidates

        result["plot"] = plot_candidates(args.plot, args.num, args.d_min, args.d_max, rig=rig,
                                         rig_name=args.rig, measure=args.measure)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"{args.kind} candidates for rig {args.rig} ({args.num}, {args.d_min}..{args.d_max} m):")
    for i, d in enumerate(c):
        print(f"  {i:3d}  {d:14.9f} m   1/d = {1.0 / d:.6f} 1/m")
    u = result["unit"]
    print(f"displacement per step ({u}): " + " ".join(f"{s:.3f}" for s in result["steps"]))
    print(f"mean step {result['mean_step']:.4f} {u}, min/max {result['min_max_ratio']:.4f}, "
          f"cv {result['cv']:.4f}, per-ray cv {result['ray_cv']:.4f}")
    print(f"effective closed-form baseline of this rig: {b_eff:.6g} m")
    if args.plot:
        print(f"figure written to {result['plot']}")
    return 0
