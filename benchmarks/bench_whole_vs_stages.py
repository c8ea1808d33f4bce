"""Whole forward against the sum of its stages, per preset, at CPU and paper size.

A jitted whole forward that costs much more than its stages compiled alone means XLA fused
something badly across a stage boundary (as the masked variance's unrolled camera sums did:
3.9x at paper size for G16V-released). Each stage is the one the whole forward runs:
features, sweep (grids from the rig, features and masks sampled), cost volume, U-Net,
regression. Batch 1, 3 cameras, eval mode, median of ``--reps`` after one warm-up.

    python benchmarks/bench_whole_vs_stages.py --sizes cpu paper --out benchmarks/results/whole_vs_stages.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import time
from pathlib import Path

import jax

from gijax.bench.cases.programs import stage_programs
from gijax.nn import get_preset

# The second network: G16VV's structure (variance, in16/f96) with plain features.
STRUCTURES = {
    "G16V-released": lambda: get_preset("G16V-released"),
    "G16VV-plain": lambda: dataclasses.replace(get_preset("G16VV"), name="G16VV-plain",
                                               features="plain"),
    "G16VV": lambda: get_preset("G16VV"),
}


STAGE_KEYS = {"features": "features", "sweep": "sweep", "cost volume": "cost_volume",
              "U-Net": "unet", "regression": "regress"}


def _cpu(cfg):
    cpu = get_preset((cfg.name if cfg.name != "G16VV-plain" else "G16VV") + "-cpu")
    return dataclasses.replace(cpu, name=cfg.name + "-cpu", features=cfg.features)


def timed(fn, args, reps: int) -> float:
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def measure(cfg, reps: int) -> dict:
    state, (sur, masks), whole, stages = stage_programs(cfg)
    row = {"preset": cfg.name, "surrogate": "x".join(map(str, cfg.surrogate_hw)),
           "whole_s": timed(jax.jit(whole), (state, sur, masks), reps)}
    x = (sur,)
    for name, fn in stages:
        jf = jax.jit(fn)
        row[STAGE_KEYS[name] + "_s"] = timed(jf, (state, *x), reps)
        out = jf(state, *x)
        x = out if isinstance(out, tuple) else (out,)
    row["sum_s"] = sum(row[k + "_s"] for k in STAGE_KEYS.values())
    row["whole_over_sum"] = row["whole_s"] / row["sum_s"]
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", nargs="+", choices=("cpu", "paper"), default=["cpu"])
    p.add_argument("--presets", nargs="+", choices=list(STRUCTURES), default=list(STRUCTURES))
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--out", default="benchmarks/out/whole_vs_stages.json")
    args = p.parse_args()
    rows = []
    cols = ("features", "sweep", "cost_volume", "unet", "regress", "sum", "whole")
    print(f"{'preset':<20}" + "".join(f"{c:>12}" for c in cols) + f"{'whole/sum':>11}")
    for size in args.sizes:
        for name in args.presets:
            cfg = STRUCTURES[name]()
            cfg = cfg if size == "paper" else _cpu(cfg)
            row = measure(cfg, args.reps)
            rows.append(row)
            print(f"{row['preset']:<20}" + "".join(f"{row[c + '_s'] * 1e3:>10.0f}ms"
                                                   for c in cols)
                  + f"{row['whole_over_sum']:>11.2f}", flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"rows": rows, "reps": args.reps, "batch": 1, "cameras": 3,
                               "jax": jax.__version__, "device": str(jax.devices()[0])},
                              indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
