"""Where a CPU training step's time goes: XLA's own per-instruction trace, by operation and
direction.

Each preset runs in a fresh process that builds the same step as ``bench_train.py`` (forward,
backward and Adam at ``--batch`` on a fixed in-memory batch,
:func:`gijax.bench.train_step.train_step_case`), compiles it with XLA's HLO dump switched on,
runs it twice untimed, then records ``--steps`` steps under ``jax.profiler.trace``. Every
executed instruction of the compiled program (a fusion, a YNNPACK library call, a gather, ...)
is one event of the trace; the dump's metadata names the JAX operation each instruction came
from (``conv_general_dilated``, ``gather``, ``reduce_sum``, ...) and whether it belongs to the
backward pass (a ``transpose(...)`` in its name stack). The first table sums the events per
operation and direction, per step; the second per network stage and direction: the stage is the
scope that ``gijax.model`` puts on each of its stages (``gijax.model.STAGES``); instructions
without one are the loss, the optimiser, and copies and fusions whose metadata XLA dropped.

The sum over instructions can exceed the step's wall time (XLA's thunk executor runs
independent instructions side by side on the two cores) and is lower than it by the host's
dispatch; both figures are printed.

    python benchmarks/bench_step_profile.py --presets G16VV-cpu-zncc,G16VV-cpu --batch 8
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Instructions of the optimised HLO, and those of them that carry the JAX operation they came
# from. Trace events with other names (the executor's and thread pool's own spans, Python
# frames, the jitted call) are not instructions and are left out.
_INSTRUCTION = re.compile(r"^\s*(?:ROOT )?%?([\w.\-]+) = ", re.M)
_WITH_OPERATION = re.compile(r"^\s*(?:ROOT )?%?([\w.\-]+) = .*?op_name=\"([^\"]+)\"", re.M)
NO_OPERATION = "(copies and layout changes: no JAX operation)"
OUTSIDE_STAGES = "(no stage: loss, optimiser, copies)"


def operation_of(op_name: str) -> str:
    """``jit(step)/transpose(jvp())/conv_general_dilated`` -> ``conv_general_dilated [bwd]``."""
    primitive = op_name.split("/")[-1]
    return primitive + (" [bwd]" if "transpose(" in op_name else "")


def stage_of(op_name: str) -> str:
    """``jit(step)/transpose(jvp(unet_logits))/conv_general_dilated`` -> ``unet_logits [bwd]``."""
    from gijax.model import STAGES

    names = [t for t in re.findall(r"[\w\-]+", op_name) if t in STAGES]
    stage = names[0] if names else OUTSIDE_STAGES
    return stage + (" [bwd]" if "transpose(" in op_name else "")


def program_text(dump: str) -> str:
    """The optimised HLO of the largest ``jit_step`` module in an XLA dump folder."""
    files = glob.glob(os.path.join(dump, "*jit_step*cpu_after_optimizations.txt"))
    if not files:
        raise RuntimeError(f"no optimised jit_step module in the XLA dump {dump}")
    return Path(max(files, key=os.path.getsize)).read_text()


def profile(preset: str, batch: int, steps: int, dump: str) -> dict:
    import jax

    from gijax.bench.train_step import train_step_case

    case = train_step_case(preset, batch)
    for _ in range(2):
        jax.block_until_ready(case.run())
    with tempfile.TemporaryDirectory() as trace_dir:
        t0 = time.perf_counter()
        with jax.profiler.trace(trace_dir):
            for _ in range(steps):
                jax.block_until_ready(case.run())
        wall = (time.perf_counter() - t0) / steps
        traces = glob.glob(os.path.join(trace_dir, "**", "*.trace.json.gz"), recursive=True)
        if not traces:
            raise RuntimeError("jax.profiler wrote no trace")
        with gzip.open(traces[0], "rt") as f:
            events = json.load(f)["traceEvents"]
    text = program_text(dump)
    origin = dict.fromkeys(_INSTRUCTION.findall(text), NO_OPERATION)
    with_op = _WITH_OPERATION.findall(text)
    origin.update({name: operation_of(op) for name, op in with_op})
    stage = dict.fromkeys(origin, OUTSIDE_STAGES)
    stage.update({name: stage_of(op) for name, op in with_op})
    ms = collections.Counter()
    count = collections.Counter()
    stage_ms = collections.Counter()
    for e in events:
        name = e.get("name", "")
        if e.get("ph") != "X" or name not in origin:
            continue
        ms[origin[name]] += e.get("dur", 0.0) / 1e3 / steps
        count[origin[name]] += 1
        stage_ms[stage[name]] += e.get("dur", 0.0) / 1e3 / steps
    rows = [{"operation": k, "ms_per_step": v, "instructions": count[k] // steps}
            for k, v in ms.most_common()]
    stages = [{"stage": k, "ms_per_step": v} for k, v in stage_ms.most_common()]
    return {"preset": preset, "batch": batch, "steps": steps, "wall_s_per_step": wall,
            "instruction_ms_per_step": sum(ms.values()), "rows": rows, "stages": stages}


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0].replace("\n", " "),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--presets", default="G16VV-cpu-zncc,G16VV-cpu",
                    help="comma-separated presets, each profiled in its own process "
                         "(default: the bundle's design and the reference)")
    ap.add_argument("--batch", type=int, default=8, help="batch of the step (default 8)")
    ap.add_argument("--steps", type=int, default=3, help="profiled steps (default 3)")
    ap.add_argument("--top", type=int, default=20, help="table rows per preset (default 20)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "step_profile.json"),
                    help="JSON file of every row (default benchmarks/out/step_profile.json)")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--dump", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(profile(args.worker, args.batch, args.steps, args.dump)))
        return 0
    results = []
    for preset in args.presets.split(","):
        with tempfile.TemporaryDirectory() as dump:
            env = dict(os.environ, JAX_PLATFORMS="cpu")
            env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") +
                                f" --xla_dump_to={dump} --xla_dump_hlo_as_text").strip()
            env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
            r = subprocess.run([sys.executable, __file__, "--worker", preset, "--dump", dump,
                                "--batch", str(args.batch), "--steps", str(args.steps)],
                               env=env, capture_output=True, text=True)
        if r.returncode != 0:
            print(r.stderr[-2000:], file=sys.stderr)
            return 1
        res = json.loads(r.stdout.strip().splitlines()[-1])
        results.append(res)
        print(f"\n{preset}, batch {res['batch']}: {res['wall_s_per_step']:.3f} s per step "
              f"(wall, under the profiler); instructions {res['instruction_ms_per_step']:.0f} "
              f"ms per step")
        print(f"{'operation':<44}{'ms/step':>9}{'share':>8}{'instr.':>8}")
        for row in res["rows"][:args.top]:
            share = row["ms_per_step"] / res["instruction_ms_per_step"]
            print(f"{row['operation'][:43]:<44}{row['ms_per_step']:>9.1f}{share:>8.1%}"
                  f"{row['instructions']:>8}")
        print(f"{'stage':<44}{'ms/step':>9}{'share':>8}")
        for row in res["stages"]:
            share = row["ms_per_step"] / res["instruction_ms_per_step"]
            print(f"{row['stage'][:43]:<44}{row['ms_per_step']:>9.1f}{share:>8.1%}")
    from gijax.io.paths import write_json_atomic

    out = write_json_atomic(args.out, {"cpu_count": os.cpu_count(), "results": results})
    print(f"\nwritten {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
