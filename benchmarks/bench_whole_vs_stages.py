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

import jax

from gijax.bench.cases.programs import stage_programs
from gijax.bench.isolated import STAGES, bench_config, stage_times
from gijax.bench.timing import time_call
from gijax.io.paths import write_json_atomic

# G16VV-plain (G16VV's structure with plain features) is the network the authors' PyTorch
# figures in benchmarks/RESULTS.md were taken on.
STRUCTURES = ("G16V-released", "G16VV-plain", "G16VV")


def cpu_name(name: str) -> str:
    """The CPU-size twin of a paper-size name (``G16VV-plain`` -> ``G16VV-cpu-plain``)."""
    if name.endswith("-plain"):
        return name[: -len("-plain")] + "-cpu-plain"
    return name + "-cpu"


def measure(cfg, reps: int) -> dict:
    state, (sur, masks), whole, stages = stage_programs(cfg)
    whole_c = jax.jit(whole)
    row = {"preset": cfg.name, "surrogate": "x".join(map(str, cfg.surrogate_hw)),
           "whole_s": time_call(lambda: whole_c(state, sur, masks), warmup=1,
                                reps=reps)[0].median}
    row.update(stage_times(state, sur, stages, reps))
    row["whole_over_sum"] = row["whole_s"] / row["sum_s"]
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", nargs="+", choices=("cpu", "paper"), default=["cpu"],
                   help="network sizes: the -cpu presets and/or the paper's")
    p.add_argument("--presets", nargs="+", choices=STRUCTURES, default=list(STRUCTURES),
                   help="network structures to time whole and stage by stage")
    p.add_argument("--reps", type=int, default=3, help="timed runs per case")
    p.add_argument("--out", default="benchmarks/out/whole_vs_stages.json",
                   help="where the JSON results are written")
    args = p.parse_args()
    rows = []
    cols = (*STAGES, "sum", "whole")
    print(f"{'preset':<20}" + "".join(f"{c:>12}" for c in cols) + f"{'whole/sum':>11}")
    for size in args.sizes:
        for name in args.presets:
            cfg = bench_config(name if size == "paper" else cpu_name(name))
            row = measure(cfg, args.reps)
            rows.append(row)
            print(f"{row['preset']:<20}" + "".join(f"{row[c + '_s'] * 1e3:>10.0f}ms"
                                                   for c in cols)
                  + f"{row['whole_over_sum']:>11.2f}", flush=True)
    out = write_json_atomic(args.out, {"rows": rows, "reps": args.reps, "batch": 1,
                                       "cameras": 3, "jax": jax.__version__,
                                       "device": str(jax.devices()[0])})
    print(f"wrote {out}")


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    main()
