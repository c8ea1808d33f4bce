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
from flax import nnx

from gijax.bench.cases import _sweep
from gijax.bench.rigs import network_inputs, network_rig
from gijax.geometry.layouts import builtin_rig
from gijax.model import create_model
from gijax.nn import get_preset, regress

# The second network: G16VV's structure (variance, in16/f96) with plain features.
STRUCTURES = {
    "G16V-released": lambda: get_preset("G16V-released"),
    "G16VV-plain": lambda: dataclasses.replace(get_preset("G16VV"), name="G16VV-plain",
                                               features="plain"),
    "G16VV": lambda: get_preset("G16VV"),
}


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
    rig = network_rig(builtin_rig("paper-train"), cfg)
    model = create_model(cfg, seed=0)
    model.eval()
    graphdef, state = nnx.split(model)
    sur, masks, cand = network_inputs(cfg, rig.num_cameras)
    b, n, hs, ws, _ = sur.shape

    def whole(state, sur, masks):
        return nnx.merge(graphdef, state)(sur, masks, rig, cand)["inv_distance"]

    def features(state, sur):
        f = nnx.merge(graphdef, state).features(sur.reshape(b * n, hs, ws, 3))
        return f.reshape(b, n, *f.shape[1:])

    def sweep(state, feats):
        return _sweep(cfg, feats, masks, rig, cand)

    def cost(state, sampled, valid):
        return nnx.merge(graphdef, state).cost_volume(sampled, valid.astype(sampled.dtype))

    def unet(state, volume):
        return nnx.merge(graphdef, state).unet(volume)

    def regression(state, logits):
        return regress(logits, cand, cfg.output_hw)["inv_distance"]

    row = {"preset": cfg.name, "surrogate": "x".join(map(str, cfg.surrogate_hw)),
           "whole_s": timed(jax.jit(whole), (state, sur, masks), reps)}
    x = (sur,)
    for name, fn in (("features", features), ("sweep", sweep), ("cost_volume", cost),
                     ("unet", unet), ("regress", regression)):
        jf = jax.jit(fn)
        row[name + "_s"] = timed(jf, (state, *x), reps)
        out = jf(state, *x)
        x = out if isinstance(out, tuple) else (out,)
    row["sum_s"] = sum(row[k + "_s"] for k in ("features", "sweep", "cost_volume", "unet",
                                                "regress"))
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
