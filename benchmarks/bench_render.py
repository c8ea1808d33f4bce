"""Render throughput of the procedural multi-fisheye renderer, and a montage of one sample.

Measures samples per second of :func:`gijax.render.render_sample` (every camera image, distance
and mask plus the 160 x 640 ground-truth panorama) at the CPU-preset rig size (the paper-train
layout scaled by 1/4: 3 x 256 x 256) and at the paper's size (3 x 1024 x 1024). Compile time is
reported separately from the steady-state time. Prints a table, writes JSON, and saves a PNG
montage (camera images, masks, camera distances, panorama distance) of one sample per style.

    PYTHONPATH=. python benchmarks/bench_render.py [--samples 3] [--paper-samples 1]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import jax
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from gijax.geometry.layouts import builtin_rig  # noqa: E402
from gijax.geometry.panorama import Panorama  # noqa: E402
from gijax.geometry.rig import scale_rig  # noqa: E402
from gijax.io.paths import save_figure_atomic, write_json_atomic  # noqa: E402
from gijax.render import render_sample  # noqa: E402
from gijax.render.render import choose_style  # noqa: E402


def _inverse_depth_rgb(dist: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Colour-map 1/d over 0.01..2 1/m (0.5 m to 100 m; sky black)."""
    inv = np.clip(1.0 / np.maximum(dist, 1e-6), 0.0, 2.0)
    x = np.clip((np.log(np.maximum(inv, 1e-3)) - np.log(0.01)) / (np.log(2.0) - np.log(0.01)),
                0, 1)
    rgb = plt.get_cmap("turbo")(x)[..., :3]
    rgb[dist >= 1e5] = 0.0
    if valid is not None:
        rgb[~valid] = 0.25
    return rgb


def save_montage(sample: dict, path: str, title: str) -> None:
    """One figure: a row of camera images, masks and distances per camera, and the panorama."""
    n = sample["images"].shape[0]
    fig = plt.figure(figsize=(3.2 * n, 3.2 * 3 + 3.0), dpi=110)
    grid = fig.add_gridspec(4, n, height_ratios=[1, 1, 1, 0.9])
    for i in range(n):
        for row, (img, name) in enumerate([
            (sample["images"][i], "image"),
            (sample["masks"][i], "mask"),
            (_inverse_depth_rgb(sample["distances"][i], sample["masks"][i] > 0), "distance"),
        ]):
            ax = fig.add_subplot(grid[row, i])
            ax.imshow(img, cmap="gray" if img.ndim == 2 else None, vmin=0, vmax=1 if img.ndim == 2
                      else None, interpolation="nearest")
            ax.set_title(f"cam {i} {name}", fontsize=8)
            ax.axis("off")
    ax = fig.add_subplot(grid[3, :])
    ax.imshow(_inverse_depth_rgb(sample["pano_distance"]), aspect="auto", interpolation="nearest")
    ax.set_title("panorama distance at the reference point (turbo on 1/d, 0.5-100 m; sky black)",
                 fontsize=8)
    ax.axis("off")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    try:
        save_figure_atomic(fig, path)
    finally:
        plt.close(fig)


def time_rig(rig, pano: Panorama, samples: int, first_seed: int = 0) -> dict:
    """Compile (first call) and steady-state time per sample of render_sample."""
    t0 = time.perf_counter()
    render_sample(rig, first_seed, pano)
    first = time.perf_counter() - t0
    times = []
    for s in range(samples):
        t0 = time.perf_counter()
        render_sample(rig, first_seed + 1 + s, pano)
        times.append(time.perf_counter() - t0)
    per = float(np.median(times))
    cam = rig.cameras[0]
    return dict(cameras=rig.num_cameras, camera_hw=[cam.height, cam.width],
                pano_hw=list(pano.shape), first_call_s=first, samples=samples,
                seconds_per_sample=per, samples_per_s=1.0 / per,
                rays_per_s=(rig.num_cameras * cam.height * cam.width + pano.height * pano.width)
                / per)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=3, help="timed samples at CPU size")
    parser.add_argument("--paper-samples", type=int, default=1,
                        help="timed samples at paper size (0 skips it)")
    parser.add_argument("--out", default="benchmarks/out/bench_render.json",
                        help="where the JSON results are written")
    parser.add_argument("--montage-dir", default="benchmarks/out",
                        help="folder of the montages of rendered samples (one PNG per style)")
    args = parser.parse_args(argv)
    pano = Panorama.hemisphere(160, 640)
    paper = builtin_rig("paper-train")
    results = {}
    cpu_rig = scale_rig(paper, 0.25)
    results["cpu-preset"] = time_rig(cpu_rig, pano, args.samples)
    if args.paper_samples > 0:
        results["paper"] = time_rig(paper, pano, args.paper_samples)
    os.makedirs(args.montage_dir, exist_ok=True)
    shown = {}
    seed = 0
    while len(shown) < 2:
        style = choose_style(seed, "mixed")
        if style not in shown:
            shown[style] = seed
            path = os.path.join(args.montage_dir, f"render_montage_{style}.png")
            save_montage(render_sample(cpu_rig, seed, pano), path,
                         f"paper-train rig at 1/4 size, seed {seed} ({style})")
            print(f"montage: {path}")
        seed += 1
    report = dict(device=str(jax.devices()[0]), platform=platform.platform(),
                  cpu_count=os.cpu_count(), results=results)
    write_json_atomic(args.out, report)
    print(f"{'size':<12}{'cameras':>16}{'panorama':>10}{'first call s':>14}{'s/sample':>10}"
          f"{'samples/s':>11}{'Mrays/s':>9}")
    for name, r in results.items():
        cams = f"{r['cameras']}x{r['camera_hw'][0]}x{r['camera_hw'][1]}"
        pan = f"{r['pano_hw'][0]}x{r['pano_hw'][1]}"
        print(f"{name:<12}{cams:>16}{pan:>10}{r['first_call_s']:>14.2f}"
              f"{r['seconds_per_sample']:>10.3f}{r['samples_per_s']:>11.3f}"
              f"{r['rays_per_s'] / 1e6:>9.3f}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    raise SystemExit(main())
