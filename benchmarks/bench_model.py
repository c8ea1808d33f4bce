"""Forward latency and memory of the stereo network for each preset, at CPU and paper size.

For every distinct network structure (E8 and G8 share one: the candidates are inputs, not
weights; likewise E16, G16 and G16V) the forward pass (surrogate images -> distance panorama,
batch 1, eval mode, random inputs) is compiled once, run ``--warmup`` times, then timed
``--reps`` times; the median (and the minimum, less sensitive to other processes on a shared
machine) is reported. Memory is XLA's own accounting of the compiled
program (``compile().memory_analysis()``: arguments + outputs + temporaries, the peak the
executable needs), and the process's resident-set growth during the first run.
G16VV is also run with the 4-camera layout (paper-test3) to measure the cost of a camera.

Usage:
  python benchmarks/bench_model.py                      # CPU-size presets (a minute or two)
  python benchmarks/bench_model.py --sizes cpu paper --reps 1   # adds the paper size (slow)
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from gijax.bench.cases.programs import structure  # noqa: E402
from gijax.bench.memory import compiled_memory, host_peak_rss_mib, rss_bytes  # noqa: E402
from gijax.geometry.layouts import builtin_rig  # noqa: E402
from gijax.geometry.rig import scale_rig  # noqa: E402
from gijax.io.paths import write_json_atomic  # noqa: E402
from gijax.model import create_model, model_grids  # noqa: E402
from gijax.nn.presets import PRESETS  # noqa: E402

PAPER_NAMES = ["E8", "G8", "E16", "G16", "G16V", "G16V-released", "G16VV"]


def rss_mb() -> float:
    return rss_bytes() / 2**20


def measure(cfg, rig_name: str, reps: int, warmup: int) -> dict:
    model = create_model(cfg, seed=0)
    model.eval()
    rig = builtin_rig(rig_name)
    if cfg.image_scale != 1.0:
        rig = scale_rig(rig, cfg.image_scale)
    n = rig.num_cameras
    hs, ws = cfg.surrogate_hw
    rng = np.random.default_rng(0)
    sur = jnp.asarray(rng.uniform(size=(1, n, hs, ws, 3)), jnp.float32)
    masks = jnp.ones((1, n, hs, ws), jnp.float32)
    cand = jnp.asarray(np.geomspace(cfg.d_min, cfg.d_max, cfg.num_candidates), jnp.float32)
    graphdef, state = nnx.split(model)

    def forward(state, sur, masks, rig, cand):
        return nnx.merge(graphdef, state)(sur, masks, model_grids(cfg, rig, cand))["distance"]

    t0 = time.perf_counter()
    compiled = jax.jit(forward).lower(state, sur, masks, rig, cand).compile()
    compile_s = time.perf_counter() - t0
    mem = compiled_memory(compiled)
    rss0 = rss_mb()
    times = []
    for i in range(warmup + reps):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(state, sur, masks, rig, cand))
        if i >= warmup:
            times.append(time.perf_counter() - t0)
        if i == 0:
            rss_delta = rss_mb() - rss0
    return dict(cameras=n, compile_s=compile_s, median_ms=1e3 * statistics.median(times),
                min_ms=1e3 * min(times),
                times_ms=[1e3 * t for t in times],
                xla_peak_mb=mem["peak_bytes"] / 2**20 if mem else None,
                xla_temp_mb=mem["temp_bytes"] / 2**20 if mem else None,
                rss_delta_mb=rss_delta, peak_rss_mb=host_peak_rss_mib())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", nargs="+", default=["cpu"], choices=["cpu", "paper"],
                        help="network sizes to time: the -cpu presets and/or the paper's")
    parser.add_argument("--presets", nargs="+", default=PAPER_NAMES,
                        help="paper preset names; the CPU size uses NAME-cpu")
    parser.add_argument("--reps", type=int, default=3, help="timed forward passes per case")
    parser.add_argument("--warmup", type=int, default=1,
                        help="untimed passes first (the first compiles)")
    parser.add_argument("--no-4cam", action="store_true", help="skip G16VV with 4 cameras")
    parser.add_argument("--out", default=os.path.join("benchmarks", "out", "bench_model.json"),
                        help="where the JSON results are written")
    args = parser.parse_args(argv)

    rows = []
    for size in args.sizes:
        done = {}
        jobs = [(name, "paper-train") for name in args.presets]
        if not args.no_4cam and "G16VV" in args.presets:
            jobs.append(("G16VV", "paper-test3"))
        for name, rig_name in jobs:
            cfg = PRESETS[name if size == "paper" else name + "-cpu"]
            key = (structure(cfg), rig_name)
            if key not in done:
                print(f"[{size}] {cfg.name} on {rig_name} ...", flush=True)
                done[key] = (cfg.name, measure(cfg, rig_name, args.reps, args.warmup))
            first, res = done[key]
            rows.append(dict(size=size, preset=cfg.name, rig=rig_name, same_as=(
                None if first == cfg.name else first), **res))

    header = (f"{'size':5s} {'preset':18s} {'cams':>4s} {'median ms':>10s} {'min ms':>9s} "
              f"{'compile s':>9s} "
              f"{'XLA peak MB':>11s} {'RSS +MB':>8s}  note")
    print(header)
    print("-" * len(header))
    for r in rows:
        note = f"same network as {r['same_as']}" if r["same_as"] else ""
        xla = "n/a" if r["xla_peak_mb"] is None else f"{r['xla_peak_mb']:.0f}"
        print(f"{r['size']:5s} {r['preset']:18s} {r['cameras']:4d} {r['median_ms']:10.1f} "
              f"{r['min_ms']:9.1f} {r['compile_s']:9.1f} {xla:>11s} {r['rss_delta_mb']:8.0f}  {note}")
    write_json_atomic(args.out, dict(device=str(jax.devices()[0]), platform=platform.platform(),
                                     cpu_count=os.cpu_count(), jax=jax.__version__,
                                     reps=args.reps, warmup=args.warmup, rows=rows))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
