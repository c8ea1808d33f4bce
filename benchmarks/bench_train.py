"""Training throughput (samples/s) per CPU preset on 1 and 2 forced CPU devices.

Each (preset, device count) runs in its own process, because the number of forced host
devices (XLA_FLAGS=--xla_force_host_platform_device_count=N) is fixed when JAX starts. A
process builds the preset's network, jits the data-parallel train step for a global batch,
runs one step to compile, then times ``--steps`` steps on a fixed in-memory batch.

    python benchmarks/bench_train.py                        # E8-cpu and G16VV-cpu, batch 2
    python benchmarks/bench_train.py --presets all --steps 5 --batch 4
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def measure(preset: str, batch: int, steps: int) -> dict:
    import jax

    from gijax.bench.train_step import time_steps, train_step_case

    case = train_step_case(preset, batch)
    dt = time_steps(case, steps)
    loss = float(case.run()["loss"])
    return {"preset": preset, "devices": len(jax.devices()), "batch": batch, "steps": steps,
            "samples_per_s": batch / dt, "s_per_step": dt,
            "setup_and_compile_s": case.compile_s, "loss": loss}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="E8-cpu,G16VV-cpu",
                    help="comma-separated CPU presets, or 'all'")
    ap.add_argument("--devices", default="1,2", help="forced CPU device counts")
    ap.add_argument("--batch", type=int, default=2, help="global batch (divisible by devices)")
    ap.add_argument("--steps", type=int, default=3, help="timed steps")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "bench_train.json"),
                    help="where the JSON results are written")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(measure(args.worker, args.batch, args.steps)))
        return 0
    from gijax.nn.presets import PRESETS

    presets = ([n for n in PRESETS if n.endswith("-cpu")] if args.presets == "all"
               else args.presets.split(","))
    rows = []
    print(f"{'preset':<20}{'devices':>8}{'batch':>7}{'samples/s':>12}{'s/step':>11}"
          f"{'compile s':>12}", flush=True)
    for preset in presets:
        for n in (int(x) for x in args.devices.split(",")):
            env = dict(os.environ)
            env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") +
                                f" --xla_force_host_platform_device_count={n}").strip()
            env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
            env["JAX_PLATFORMS"] = "cpu"
            r = subprocess.run([sys.executable, __file__, "--worker", preset, "--batch",
                                str(args.batch), "--steps", str(args.steps)], env=env,
                               capture_output=True, text=True)
            if r.returncode != 0:
                print(r.stderr[-2000:], file=sys.stderr)
                return 1
            rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
            row = rows[-1]
            print(f"{row['preset']:<20}{row['devices']:>8}{row['batch']:>7}"
                  f"{row['samples_per_s']:>12.2f}{row['s_per_step']:>11.2f}"
                  f"{row['setup_and_compile_s']:>12.1f}", flush=True)
    from gijax.io.paths import write_json_atomic

    out = write_json_atomic(args.out, {"cpu_count": os.cpu_count(), "rows": rows})
    print(f"written {out}")
    return 0


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
