"""Cases that time the network's programs: the forward pass per preset, the sphere sweep
alone, the forward cut into stages, and the scaling with cameras and candidates."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from gijax.bench.cases.context import Context, measure_program, program_row, timing_row
from gijax.bench.cases.programs import (eval_forward_program, rig_sweep, stage_programs,
                                        structure)
from gijax.bench.cost import compile_fn
from gijax.bench.memory import CaseMemory, compiled_memory
from gijax.bench.rigs import network_inputs, network_rig, polygon_rig, with_candidates
from gijax.bench.timing import linear_increment, paired_ratio, timing_stats, time_alternating
from gijax.geometry.layouts import builtin_rig
from gijax.nn.presets import get_preset


def forward(ctx: Context) -> dict:
    """Forward latency, memory and FLOP efficiency per preset (3-camera training rig)."""
    rows, done = [], {}
    base_rig = builtin_rig("paper-train")
    for name in ctx.settings.presets:
        cfg = get_preset(name)
        key = structure(cfg)
        if key not in done:
            ctx.log(f"forward {name} ...")
            rig = network_rig(base_rig, cfg)
            row, _, _ = measure_program(ctx, lambda: eval_forward_program(cfg, rig))
            done[key] = (name, row)
        first, row = done[key]
        rows.append({"preset": name, "same_as": None if first == name else first,
                     "surrogate": "x".join(map(str, cfg.surrogate_hw)),
                     "output": "x".join(map(str, cfg.output_hw)), **row})
    return {"rows": rows}


def sweep(ctx: Context) -> dict:
    """The sphere sweep alone (grids from the rig + sampling of features and masks), with its
    memory traffic against the measured bandwidth."""
    cfg = get_preset(ctx.settings.sweep_preset)
    rig = network_rig(builtin_rig("paper-train"), cfg)
    n = rig.num_cameras
    hf, wf = cfg.feature_hw
    rng = np.random.default_rng(0)
    feats = jnp.asarray(rng.standard_normal((1, n, hf, wf, cfg.feature_channels)), jnp.float32)
    _, masks, cand = network_inputs(cfg, n)

    def run(feats, masks, rig, cand):
        return rig_sweep(cfg, feats, masks, rig, cand)

    ctx.log(f"sweep {cfg.name} ...")
    row, compiled, _ = measure_program(ctx, lambda: (compile_fn(run, feats, masks, rig, cand),
                                                      (feats, masks, rig, cand)))
    mem = compiled_memory(compiled)
    # The least traffic: read the inputs once, write the outputs once.
    min_bytes = mem.get("argument_bytes", 0) + mem.get("output_bytes", 0)
    row.update({"preset": cfg.name, "cameras": n, "candidates": cfg.num_candidates,
                "volume": f"{n}x{cfg.num_candidates}x{cfg.cost_hw[0]}x{cfg.cost_hw[1]}x"
                          f"{cfg.feature_channels}",
                "min_gbytes": min_bytes / 1e9})
    if ctx.limits:
        secs = row["ms_median"] / 1e3
        row["min_bytes_frac_bandwidth"] = min_bytes / secs / ctx.limits["bytes_per_s"]
        row["bandwidth_bound_ms"] = 1e3 * min_bytes / ctx.limits["bytes_per_s"]
    return {"rows": [row]}


def stages(ctx: Context) -> dict:
    """The forward pass cut into its stages (feature extractor, sweep, cost volume, U-Net,
    regression), each compiled and timed alone with its FLOPs and bytes: where the time goes
    and how far each stage is from the machine's limits."""
    cfg = get_preset(ctx.settings.sweep_preset)
    state, (sur, _), _, stage_fns = stage_programs(cfg)
    rows, x = [], (sur,)
    for name, fn in stage_fns:
        ctx.log(f"stage {cfg.name} {name} ...")
        args = (state, *x)
        row, compiled, _ = measure_program(ctx, lambda fn=fn, args=args: (compile_fn(fn, *args),
                                                                           args))
        out = compiled(*args)
        x = out if isinstance(out, tuple) else (out,)
        shapes = [tuple(a.shape) for a in jax.tree_util.tree_leaves(out)][:1]
        rows.append({"preset": cfg.name, "stage": name, "output": "x".join(map(str, shapes[0])),
                     **{k: v for k, v in row.items() if not k.startswith("rss")}})
    total = sum(r["ms_median"] for r in rows)
    for r in rows:
        r["share"] = r["ms_median"] / total
    return {"rows": rows, "sum_ms": total}


def scaling(ctx: Context) -> dict:
    """Forward time and memory of one preset against the camera count (regular-polygon rigs,
    1 m sides) and the candidate count; every point timed in the same alternating rounds."""
    s = ctx.settings
    base = get_preset(s.scaling_preset)
    points = [(n, base.num_candidates) for n in s.scaling_cameras]
    points += [(s.scaling_cameras[0], d) for d in s.scaling_candidates
               if (s.scaling_cameras[0], d) not in points]
    progs, rows = {}, {}
    for cams, cands in points:
        ctx.log(f"scaling {base.name}: {cams} cameras, {cands} candidates ...")
        cfg = base if cands == base.num_candidates else with_candidates(base, cands)
        rig = network_rig(polygon_rig(cams), cfg)
        with CaseMemory() as mem:
            t0 = time.perf_counter()
            compiled, args = eval_forward_program(cfg, rig)
            compile_s = time.perf_counter() - t0
            jax.block_until_ready(compiled(*args))
        progs[(cams, cands)] = (compiled, args)
        rows[(cams, cands)] = {"preset": base.name, "cameras": cams, "candidates": cands,
                               "compile_s": compile_s, **mem.result()}
    times = time_alternating({k: (lambda c=c, a=a: c(*a)) for k, (c, a) in progs.items()},
                             warmup=max(ctx.warmup - 1, 0), reps=s.scaling_reps)
    for key, row in rows.items():
        stats = timing_stats(times[key])
        row.update(timing_row(stats))
        row.update(program_row(progs[key][0], stats.median, ctx.limits))
    d0 = base.num_candidates
    cam_rows = [rows[(n, d0)] for n in s.scaling_cameras]
    cand_rows = [rows[(s.scaling_cameras[0], d)] for d in s.scaling_candidates]
    out = {"rows": list(rows.values()), "raw_ms": {f"{k[0]}cam_{k[1]}cand":
                                                    [1e3 * t for t in v]
                                                    for k, v in times.items()}}
    if len(cam_rows) > 1:
        out["ms_per_camera"] = linear_increment([r["cameras"] for r in cam_rows],
                                                [r["ms_median"] for r in cam_rows])
        out["mib_per_camera"] = linear_increment([r["cameras"] for r in cam_rows],
                                                 [r.get("xla_peak_mib", 0.0) for r in cam_rows])
        first = (s.scaling_cameras[0], d0)
        for n in s.scaling_cameras[1:]:
            rows[(n, d0)]["ratio_vs_first"] = paired_ratio(times[(n, d0)], times[first]).median
    if len(cand_rows) > 1:
        out["ms_per_candidate"] = linear_increment([r["candidates"] for r in cand_rows],
                                                   [r["ms_median"] for r in cand_rows])
        out["mib_per_candidate"] = linear_increment(
            [r["candidates"] for r in cand_rows], [r.get("xla_peak_mib", 0.0) for r in cand_rows])
    return out
