"""Rig layout design: gradient-based optimisation vs random and grid search, then validation.

For 3, 4 and 5 cameras in a footprint (default a 1 m square):

1. Optimise the layout objective of :mod:`gijax.design` with Adam from several random starts.
2. Give random search and grid search the same number of objective evaluations and compare the
   best penalised objective reached vs evaluations (plotted). Accounting: one evaluation is one
   value of the penalised objective for one layout; an Adam step on K starts counts K
   evaluations (each a value plus its gradient; the measured cost ratio is reported).
3. Validate: render test scenes for the best optimised layout and for the paper-style layout of
   the same footprint (centred regular polygon: the paper-test3 square for 4 cameras, a
   triangle as paper-test2 for 3, a pentagon for 5), estimate distance with a trained variance
   model (``--ckpt RUN``, G16VV-cpu, candidates recomputed for each rig) or, without a
   checkpoint, with the classical RTSS baseline (RS-G16, candidates recomputed for each rig),
   and measure the inverse-distance MAE; report the rank correlation between the objective and
   the measured MAE across layouts.

Writes ``<out>.md``, ``<out>.json`` and ``<out>.png`` (default
``experiments/out/layout_design_<scale>``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.provenance import revision  # noqa: E402
from experiments.reporting import save_png, write_json, write_text  # noqa: E402
from gijax.bench.machine import machine_info  # noqa: E402
from gijax.bench.report import markdown_grid  # noqa: E402

SCALES = {
    # starts x steps of Adam, rendered validation samples, image scale, output panorama height
    "smoke": dict(starts=4, steps=30, samples=1, image_scale=0.125, pano_h=40),
    "cpu": dict(starts=8, steps=150, samples=4, image_scale=0.25, pano_h=80),
}


def search_comparison(spec, starts: int, steps: int, seed: int) -> dict:
    from gijax.design import (evaluate_layouts, grid_search, optimize_layout, random_search,
                              regular_layout, stack_layouts)

    adam = optimize_layout(spec, starts=starts, steps=steps, seed=seed, lr=0.05, progress=True)
    budget = adam.evaluations
    rnd = random_search(spec, budget, seed=seed, batch=starts)
    grid = grid_search(spec, budget, batch=starts)
    # Warm timings of one batch (compilation excluded) for the cost of a value vs a gradient.
    from gijax.design.optimize import adam_step

    tx, step = adam_step(spec, 0.05, steps)
    lays = adam.layouts
    state = tx.init(lays)
    jax.block_until_ready(step(lays, state))
    t0 = time.perf_counter()
    for _ in range(3):
        jax.block_until_ready(step(lays, state))
    grad_s = (time.perf_counter() - t0) / 3 / starts
    evaluate_layouts(lays, spec, starts)
    t0 = time.perf_counter()
    for _ in range(3):
        evaluate_layouts(lays, spec, starts)
    value_s = (time.perf_counter() - t0) / 3 / starts
    regular = evaluate_layouts(stack_layouts([regular_layout(spec)]), spec, starts)
    evals, best = adam.best_so_far()
    return {
        "adam": adam, "random": rnd, "grid": grid, "budget": budget,
        "regular_total": float(regular["total"][0]),
        "regular_objective": float(regular["objective"][0]),
        "curves": {"adam": (evals.tolist(), best.tolist()),
                   "random": (list(range(1, rnd["evaluations"] + 1)), rnd["best_so_far"].tolist()),
                   "grid": (list(range(1, grid["evaluations"] + 1)),
                            grid["best_so_far"].tolist())},
        "seconds_per_value": value_s, "seconds_per_gradient_step": grad_s,
    }


def plot_curves(results: dict, footprint: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(5 * len(results), 4.2), squeeze=False)
    for ax, (n, r) in zip(axes[0], results.items()):
        for name, style in (("adam", "-"), ("random", "--"), ("grid", ":")):
            x, y = r["curves"][name]
            label = {"adam": f"Adam ({r['adam'].history.shape[1]} starts)",
                     "random": "random search",
                     "grid": f"grid search ({r['grid']['per_side']}x{r['grid']['per_side']} "
                             "lattice)"}[name]
            ax.plot(x, y, style, lw=1.6, label=label)
        ax.axhline(r["regular_total"], color="k", lw=0.8, label="paper-style layout")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("objective evaluations")
        ax.set_ylabel("best penalised objective (1/m)")
        ax.set_title(f"{n} cameras, {footprint:g} m square", fontsize=10)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.tight_layout()
    save_png(fig, path, dpi=110)
    plt.close(fig)


def validate(layouts: dict, spec_of: dict, cfg: dict, ckpt: str | None, seed: int) -> list:
    """MAE (1/m) of the predictor on rendered test scenes for each named layout."""
    from gijax.candidates import rig_gi_candidates
    from gijax.design import layout_rig
    from gijax.geometry.panorama import Panorama
    from gijax.render import render_sample
    from gijax.evaluate.metrics import evaluate_batch

    pano = Panorama.hemisphere(cfg["pano_h"], 4 * cfg["pano_h"])
    model = None
    if ckpt:
        from gijax.predict import predict
        from gijax.store import load_model

        model, mc, _ = load_model(ckpt)  # a run folder, an inference bundle or a bundled name
        scale = mc.image_scale
        pano = Panorama.hemisphere(*mc.output_hw)  # labels at the network's output size
    else:
        from gijax.baseline.rtss import rtss_predict_sample

        scale = cfg["image_scale"]
    rows = []
    for name, lay in layouts.items():
        spec = spec_of[name]
        t0 = time.perf_counter()
        full = layout_rig(lay, spec)
        small = layout_rig(lay, spec, image_scale=scale)
        sums = []
        for i in range(cfg["samples"]):
            sample = render_sample(small, 50_000 + seed * 100 + i, pano=pano)
            dist = sample["pano_distance"]
            if model is not None:
                cand = rig_gi_candidates(full, int(model.config.num_candidates),
                                         model.config.d_min, model.config.d_max)
                out = predict(model, full, sample["images"], sample["masks"], cand)
                inv, valid = out["inv_distance"], out["valid"]
            else:
                cand = rig_gi_candidates(full, 16, spec.d_min, spec.d_max)
                out = rtss_predict_sample(small, sample, "RS-G16",
                                          candidates=jnp.asarray(cand, jnp.float32))
                inv, valid = out["inv_distance"], out["valid"]
            valid = np.asarray(valid, bool) & np.isfinite(inv)
            inv = np.where(valid, inv, 0.0)
            m = evaluate_batch(jnp.asarray(inv[None], jnp.float32), jnp.asarray(dist[None]),
                               jnp.asarray(valid[None]), jnp.asarray(cand, jnp.float32))
            sums.append((m["mae"] * m["pixels"], m["pixels"], float(valid.mean())))
        pix = sum(s[1] for s in sums)
        rows.append({"layout": name, "cameras": spec.num_cameras,
                     "mae": sum(s[0] for s in sums) / max(pix, 1),
                     "valid_fraction": float(np.mean([s[2] for s in sums])),
                     "samples": cfg["samples"], "panorama": f"{pano.height}x{pano.width}",
                     "seconds": time.perf_counter() - t0})
        print(f"  validated {name}: MAE {rows[-1]['mae']:.4f} 1/m", flush=True)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scale", choices=list(SCALES), default="smoke",
                   help="search and validation sizes (SCALES): smoke checks the pipeline")
    p.add_argument("--cameras", type=int, nargs="+", default=[3, 4, 5],
                   help="camera counts whose layouts are designed")
    p.add_argument("--footprint", type=float, default=1.0, help="square side, metres")
    p.add_argument("--ckpt", help="run folder of a trained variance model (G16VV-cpu)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the search starts, the random search and the validation scenes")
    p.add_argument("--out", help="output stem (default experiments/out/layout_design_<scale>)")
    args = p.parse_args(argv)
    cfg = SCALES[args.scale]
    out = Path(args.out or Path(__file__).resolve().parent / "out" / f"layout_design_{args.scale}")
    t_start = time.perf_counter()

    from gijax.design import DesignSpec, constraint_report, regular_layout

    results, layouts, spec_of, durations = {}, {}, {}, {}
    for n in args.cameras:
        spec = DesignSpec(num_cameras=n, footprint=args.footprint)
        t0 = time.perf_counter()
        r = search_comparison(spec, cfg["starts"], cfg["steps"], args.seed)
        durations[f"search_{n}"] = time.perf_counter() - t0
        results[n] = r
        layouts[f"optimised-{n}"] = r["adam"].best
        layouts[f"paper-style-{n}"] = regular_layout(spec)
        spec_of[f"optimised-{n}"] = spec_of[f"paper-style-{n}"] = spec
        r["constraints"] = constraint_report(r["adam"].best, spec)
        print(f"{n} cameras: Adam {r['adam'].final.min():.5f}, random "
              f"{r['random']['values'].min():.5f}, grid {r['grid']['values'].min():.5f}, "
              f"paper-style {r['regular_total']:.5f} ({durations[f'search_{n}']:.0f} s)",
              flush=True)
    plot_curves(results, args.footprint, out.with_suffix(".png"))

    t0 = time.perf_counter()
    predictor = ("trained variance model " + args.ckpt) if args.ckpt else \
        "classical RTSS baseline (RS-G16), NOT the trained model: no --ckpt given"
    print(f"validating with the {predictor}", flush=True)
    val = validate(layouts, spec_of, cfg, args.ckpt, args.seed)
    durations["validation"] = time.perf_counter() - t0
    from gijax.design import evaluate_layouts, stack_layouts
    for row in val:
        spec = spec_of[row["layout"]]
        rep = evaluate_layouts(stack_layouts([layouts[row["layout"]]]), spec, cfg["starts"])
        row["objective"] = float(rep["objective"][0])
        row["hard_coverage"] = float(rep["hard_coverage"][0])
        lay = layouts[row["layout"]]
        row["positions"] = np.asarray(lay.positions, np.float64).round(3).tolist()
        row["tilt_deg"] = np.degrees(np.linalg.norm(
            np.asarray(lay.rotvecs, np.float64)[:, :2], axis=1)).round(2).tolist()
    from scipy.stats import spearmanr

    rho = float(spearmanr([r["objective"] for r in val], [r["mae"] for r in val])[0]) \
        if len(val) > 2 else float("nan")
    durations["total"] = time.perf_counter() - t_start

    search_rows = []
    for n, r in results.items():
        search_rows.append({
            "cameras": n, "budget": r["budget"], "adam": float(r["adam"].final.min()),
            "random": float(r["random"]["values"].min()), "grid": float(r["grid"]["values"].min()),
            "grid_evaluations": r["grid"]["evaluations"], "grid_lattice": r["grid"]["per_side"],
            "paper_style": r["regular_total"], "adam_seconds": r["adam"].seconds,
            "random_seconds": r["random"]["seconds"], "grid_seconds": r["grid"]["seconds"],
            "ms_per_value": 1e3 * r["seconds_per_value"],
            "ms_per_gradient_step": 1e3 * r["seconds_per_gradient_step"],
            "adam_final_per_start": r["adam"].final.tolist(),
            "adam_improved_every_start": bool(np.all(r["adam"].history[-1]
                                                     < r["adam"].history[0])),
            "best_layout": {
                "positions": np.asarray(r["adam"].best.positions, np.float64).round(4).tolist(),
                "rotvecs": np.asarray(r["adam"].best.rotvecs, np.float64).round(4).tolist()},
            "best_terms": r["adam"].best_terms, "constraints": r["constraints"],
        })
    meta = {"command": " ".join([Path(sys.argv[0]).name] + (argv or sys.argv[1:])),
            "scale": args.scale, "config": cfg, "seed": args.seed, "footprint": args.footprint,
            "git_revision": revision(), "machine": machine_info(),
            "durations_s": {k: round(v, 2) for k, v in durations.items()},
            "predictor": predictor}
    payload = {"meta": meta, "search": search_rows, "validation": val,
               "spearman_objective_vs_mae": rho}
    write_json(out.with_suffix(".json"), payload)

    md = [f"# Layout design ({args.scale})", "",
          f"Command `{meta['command']}`, seed {args.seed}, git {meta['git_revision'][:12]}, "
          f"{meta['machine']['platform']}, {meta['machine']['cpu_count']} CPUs; total "
          f"{durations['total']:.0f} s.", "",
          "## Search at equal evaluations (penalised objective J, 1/m, lower is better)", "",
          "One evaluation = one objective value of one layout; an Adam step counts one "
          "evaluation per start (its value and gradient).", "",
          markdown_grid(["cameras", "evaluations", "Adam", "random", "grid (lattice, evals)",
                         "paper-style", "ms/value", "ms/grad step"],
                        [[str(r["cameras"]), str(r["budget"]), f"{r['adam']:.5f}",
                          f"{r['random']:.5f}",
                          f"{r['grid']:.5f} ({r['grid_lattice']}x{r['grid_lattice']}, "
                          f"{r['grid_evaluations']})", f"{r['paper_style']:.5f}",
                          f"{r['ms_per_value']:.2f}", f"{r['ms_per_gradient_step']:.2f}"]
                         for r in search_rows]),
          "", f"## Validation: {predictor}", "",
          f"{cfg['samples']} rendered scene(s) per layout, images at scale "
          f"{cfg['image_scale'] if not args.ckpt else 'of the model'}, panorama "
          f"{val[0]['panorama'] if val else '-'}; candidates recomputed for each rig.", "",
          markdown_grid(["layout", "objective J", "coverage", "MAE (1/m)", "valid",
                         "positions (m)"],
                        [[r["layout"], f"{r['objective']:.5f}", f"{r['hard_coverage']:.3f}",
                          f"{r['mae']:.4f}", f"{r['valid_fraction']:.2f}", str(r["positions"])]
                         for r in val]),
          "", f"Spearman rank correlation of J and MAE across the {len(val)} layouts: "
              f"{rho:.2f}.", ""]
    write_text(out.with_suffix(".md"), "\n".join(md))
    print("\n".join(md))
    print(f"wrote {out.with_suffix('.md')}, {out.with_suffix('.json')}, {out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    raise SystemExit(main())
