"""``gijax design``: optimise a camera layout in a footprint and write the rig file."""

from __future__ import annotations

import json

from gijax.cli.options import HelpFormatter


def _run(args) -> int:
    import numpy as np

    from gijax.design import (DesignSpec, constraint_report, evaluate_layouts, layout_rig,
                              optimize_layout, regular_layout, stack_layouts)
    from gijax.design.figure import plot_design
    from gijax.io.rigfile import save_rig

    spec = DesignSpec(num_cameras=args.cameras, footprint=args.footprint, shape=args.shape,
                      min_separation=args.min_separation, orientations=not args.no_tilt,
                      max_tilt_deg=args.max_tilt, heights=args.heights,
                      num_candidates=args.candidates)
    res = optimize_layout(spec, starts=args.starts, steps=args.steps, seed=args.seed,
                          lr=args.lr, progress=not args.quiet)
    report = constraint_report(res.best, spec)
    if not report["feasible"]:
        raise SystemExit(f"no start reached a feasible layout (worst violations {report}); "
                         "try more --starts or --steps")
    regular = evaluate_layouts(stack_layouts([regular_layout(spec)]), spec, args.starts)
    rig = layout_rig(res.best, spec)
    out = save_rig(rig, args.out)
    t = res.best_terms
    summary = {
        "out": str(out), "cameras": spec.num_cameras, "footprint": spec.footprint,
        "shape": spec.shape, "objective": t["objective"], "resolution": t["resolution"],
        "coverage": t["coverage"], "hard_coverage": t["hard_coverage"],
        "mean_step_px": t["mean_step_px"],
        "regular_layout_objective": float(regular["objective"][0]),
        "positions": np.asarray(res.best.positions, np.float64).round(4).tolist(),
        "rotvecs": np.asarray(res.best.rotvecs, np.float64).round(4).tolist(),
        "candidates": [round(c, 4) for c in t["candidates"]],
        "constraints": report, "evaluations": res.evaluations, "seconds": round(res.seconds, 2),
    }
    if args.plot:
        summary["plot"] = str(plot_design(res.best, spec, args.plot, res.history,
                                          title=f"designed {spec.num_cameras}-camera rig, "
                                                f"J = {t['objective']:.5f} 1/m"))
    if args.json:
        print(json.dumps(summary, indent=1))
        return 0
    print(f"wrote {out}")
    print(f"objective J = {t['objective']:.5f} 1/m (regular layout of this footprint: "
          f"{summary['regular_layout_objective']:.5f}); resolution {t['resolution']:.5f} "
          f"1/m per px, coverage {100 * t['hard_coverage']:.1f}% (soft "
          f"{100 * t['coverage']:.1f}%), mean GI step {t['mean_step_px']:.1f} px")
    for i, (p, w) in enumerate(zip(summary["positions"], summary["rotvecs"])):
        print(f"  cam{i}: position ({p[0]:+.4f}, {p[1]:+.4f}) m, axis-angle "
              f"({w[0]:+.4f}, {w[1]:+.4f}, {w[2]:+.4f}) rad")
    print(f"min separation {report['min_separation']:.4f} m, min distance to occluder axis "
          f"{report['min_occluder_distance']:.4f} m, max tilt {report['max_tilt_deg']:.2f} deg; "
          f"{res.evaluations} evaluations in {res.seconds:.1f} s")
    if args.plot:
        print(f"wrote {summary['plot']}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "design", help="optimise camera positions and tilts in a footprint; write a rig file",
        description="Gradient-based design of a fisheye rig: minimises the predicted "
                    "inverse-distance error over the panorama (step resolution of the layout's "
                    "own rig-aware GI candidates, weighted by how many unoccluded cameras see "
                    "each ray, with unmatched rays costing a blind guess) under footprint, "
                    "separation, occluder and tilt constraints, with Adam from several random "
                    "starts. Writes a gijax YAML rig file (synthetic 195 deg equidistant "
                    "cameras, LiDAR-like occluder at the footprint's centre). See docs/design.md.",
        formatter_class=HelpFormatter)
    p.add_argument("--cameras", type=int, default=4, help="number of cameras")
    p.add_argument("--footprint", type=float, default=1.0,
                   help="side of the square (or diameter of the disc) holding the cameras, m")
    p.add_argument("--shape", choices=["square", "disc"], default="square",
                   help="footprint shape")
    p.add_argument("--min-separation", type=float, default=0.2,
                   help="smallest distance between camera centres, m")
    p.add_argument("--max-tilt", type=float, default=30.0,
                   help="largest optical-axis tilt from the viewing axis, degrees")
    p.add_argument("--no-tilt", action="store_true",
                   help="keep every camera looking along the viewing axis (positions only)")
    p.add_argument("--heights", action="store_true",
                   help="also optimise camera heights (0..0.2 m above the mounting plane)")
    p.add_argument("--candidates", type=int, default=16,
                   help="number of GI candidates whose steps are measured")
    p.add_argument("--starts", type=int, default=8, help="random starts (run in parallel)")
    p.add_argument("--steps", type=int, default=150, help="Adam steps per start")
    p.add_argument("--lr", type=float, default=0.05, help="initial Adam step (m / rad)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random starts")
    p.add_argument("--out", required=True, metavar="RIG.yaml", help="rig file to write")
    p.add_argument("--plot", metavar="OUT.png",
                   help="write a figure: layout, cameras per ray, convergence")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_run)
