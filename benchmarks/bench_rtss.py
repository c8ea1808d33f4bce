"""Time and memory of the sphere-sweep stereo baseline vs cameras and candidates; optional
accuracy of the four paper configurations on rendered samples.

Prints a table and writes JSON (``--out``, default benchmarks/out/bench_rtss.json).

  python benchmarks/bench_rtss.py                    # CPU size and a larger size
  python benchmarks/bench_rtss.py --eval 2           # plus MAE / RMSE on 2 rendered samples
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from gijax.baseline.rtss import (RTSSConfig, get_rtss_preset, sphere_sweep,  # noqa: E402
                                 preset_candidates, rtss_predict_sample)
from gijax.bench.memory import compiled_memory, host_peak_rss_mib  # noqa: E402
from gijax.geometry.layouts import builtin_rig  # noqa: E402
from gijax.geometry.panorama import Panorama  # noqa: E402
from gijax.geometry.rig import scale_rig  # noqa: E402
from gijax.io.paths import write_json_atomic  # noqa: E402

RIGS = {3: "paper-train", 4: "paper-test3"}
SIZES = {  # name: (rig image scale, matching size, panorama)
    "cpu": (0.125, 128, (40, 160)),
    "large": (0.25, 256, (80, 320)),
}


def _masks(rig):
    return np.stack([np.ones((c.height, c.width), np.float32) if m is None else np.asarray(m)
                     for c, m in zip(rig.cameras, rig.masks)])


def time_one(size: str, ncam: int, ncand: int, repeats: int) -> dict:
    scale, match, (ph, pw) = SIZES[size]
    rig = scale_rig(builtin_rig(RIGS[ncam]), scale)
    cam = rig.cameras[0]
    rng = np.random.default_rng(0)
    images = rng.uniform(size=(ncam, cam.height, cam.width, 3)).astype(np.float32)
    cands = (1.0 / np.linspace(2.0, 0.01, ncand)).astype(np.float32)
    pano = Panorama.hemisphere(ph, pw)
    cfg = RTSSConfig(match_size=match, filter_levels=5)
    args = (rig, images, _masks(rig), cands)
    t0 = time.perf_counter()
    compiled = sphere_sweep.lower(*args, pano, cfg).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - t0)
    mem = compiled_memory(compiled)
    peak = mem["peak_bytes"] / 2**20 if mem else None
    return dict(size=size, cameras=ncam, candidates=ncand, image=cam.width, match=match,
                pano=f"{ph}x{pw}", compile_s=compile_s, time_ms=1e3 * float(np.median(times)),
                xla_peak_mib=peak)


def evaluate(samples: int, scale: float, pano_hw) -> list[dict]:
    from gijax.render import render_sample

    rows = []
    pano = Panorama.hemisphere(*pano_hw)
    for rig_name in ("paper-train", "paper-test3"):
        rig = scale_rig(builtin_rig(rig_name), scale)
        data = [render_sample(rig, 1000 + i, pano=pano) for i in range(samples)]
        for preset in ("RS-E16", "RS-G16", "RS-E32", "RS-G32"):
            cands = preset_candidates(rig, get_rtss_preset(preset))
            errs, sq, cover = [], [], []
            for s in data:
                out = rtss_predict_sample(rig, s, preset, candidates=cands, filter_levels=4)
                gt = np.clip(1.0 / s["pano_distance"], 0.01, 2.0)
                v = out["valid"]
                errs.append(np.abs(out["inv_distance"][v] - gt[v]))
                sq.append((out["inv_distance"][v] - gt[v]) ** 2)
                cover.append(v.mean())
            e, q = np.concatenate(errs), np.concatenate(sq)
            rows.append(dict(rig=rig_name, preset=preset, samples=samples,
                             mae=float(e.mean()), rmse=float(np.sqrt(q.mean())),
                             valid_fraction=float(np.mean(cover))))
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", nargs="+", default=list(SIZES), choices=list(SIZES),
                   help="image and panorama sizes to time")
    p.add_argument("--cameras", nargs="+", type=int, default=[3, 4], choices=[3, 4],
                   help="camera counts (paper-train's 3 cameras, paper-test3's 4)")
    p.add_argument("--candidates", nargs="+", type=int, default=[16, 32],
                   help="candidate counts of the sweep")
    p.add_argument("--repeats", type=int, default=2, help="alternating timed runs per case")
    p.add_argument("--eval", type=int, default=0, metavar="N",
                   help="also report MAE / RMSE on N rendered samples per rig (slow on CPU)")
    p.add_argument("--eval-scale", type=float, default=0.125,
                   help="image scale of the --eval samples (of the 1024 px fisheyes)")
    p.add_argument("--out", default=os.path.join("benchmarks", "out", "bench_rtss.json"),
                   help="where the JSON results are written")
    a = p.parse_args(argv)
    rows = []
    print(f"{'size':6} {'cams':>4} {'cands':>5} {'image':>5} {'match':>5} {'pano':>7} "
          f"{'compile s':>9} {'time ms':>8} {'XLA MiB':>8}")
    for size in a.sizes:
        for ncam in a.cameras:
            for ncand in a.candidates:
                r = time_one(size, ncam, ncand, a.repeats)
                rows.append(r)
                print(f"{r['size']:6} {r['cameras']:4d} {r['candidates']:5d} {r['image']:5d} "
                      f"{r['match']:5d} {r['pano']:>7} {r['compile_s']:9.1f} {r['time_ms']:8.1f} "
                      f"{r['xla_peak_mib'] or float('nan'):8.1f}", flush=True)
    result = dict(device=str(jax.devices()[0]), timing=rows,
                  max_rss_mib=host_peak_rss_mib())
    if a.eval:
        result["accuracy"] = evaluate(a.eval, a.eval_scale, (40, 160))
        print(f"\n{'rig':12} {'preset':7} {'MAE':>7} {'RMSE':>7} {'valid':>6}")
        for r in result["accuracy"]:
            print(f"{r['rig']:12} {r['preset']:7} {r['mae']:7.4f} {r['rmse']:7.4f} "
                  f"{r['valid_fraction']:6.3f}")
    write_json_atomic(a.out, result)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
