"""One optimiser step (forward, backward, Adam) of a preset on one device, and the step's
stages (forward and backward) each compiled and timed alone."""

from __future__ import annotations

import time

import jax
import numpy as np

from gijax.bench.cases.context import Context, measure_program, program_row, timing_row
from gijax.bench.cases.programs import stage_programs, with_backward
from gijax.bench.cost import compile_fn
from gijax.bench.memory import CaseMemory
from gijax.bench.rigs import network_inputs, network_rig
from gijax.bench.timing import time_call
from gijax.geometry.layouts import builtin_rig
from gijax.nn.presets import get_preset


def train_step(ctx: Context) -> dict:
    """One optimiser step (forward, backward, Adam) of a preset on one device."""
    from gijax.model import create_model
    from gijax.train import step as S
    from gijax.train.config import TrainConfig

    s = ctx.settings
    rows = []
    for name in s.train_presets:
        ctx.log(f"train step {name} batch {s.train_batch} ...")
        cfg = TrainConfig(preset=name, batch_size=s.train_batch)
        mc = cfg.model_config()
        rig = network_rig(builtin_rig("paper-train"), mc)
        with CaseMemory() as mem:
            t0 = time.perf_counter()
            model = create_model(mc, 0)
            tdef, _, params, rest = S.split_model(model)
            tx = S.make_optimizer(cfg)
            mesh = S.make_mesh([ctx.device])
            state = S.place_state(S.init_state(params, rest, tx), mesh)
            step = S.jit_train_step(S.build_train_step(tdef, tx, mc.loss), mesh)
            rng = np.random.default_rng(0)
            sur, masks, cand = network_inputs(mc, rig.num_cameras, s.train_batch)
            h, w = mc.output_hw
            batch = S.place_batch({
                "surrogates": np.asarray(sur), "masks": np.asarray(masks),
                "distance": rng.uniform(0.5, 20, (s.train_batch, h, w)).astype(np.float32),
                "valid": np.ones((s.train_batch, h, w), bool)}, mesh)
            compiled = step.lower(state, batch, rig, cand).compile()
            compile_s = time.perf_counter() - t0
            holder = {"state": state}

            def one():
                holder["state"], out = compiled(holder["state"], batch, rig, cand)
                return out

            jax.block_until_ready(one())
        stats, _ = time_call(one, warmup=max(ctx.warmup - 1, 0), reps=s.train_steps)
        row = {"preset": name, "batch": s.train_batch, "compile_s": compile_s,
               **timing_row(stats), "samples_per_s": s.train_batch / stats.median,
               **mem.result(), **program_row(compiled, stats.median, ctx.limits)}
        rows.append(row)
    return {"rows": rows}


def train_stages(ctx: Context) -> dict:
    """The training step's network cut into its stages, as :func:`stages` cuts the forward, at
    the training batch in training mode: each stage's forward, and its forward and backward
    (the gradient with respect to the weights and, after the first stage, to its input),
    compiled and timed alone, with XLA's FLOPs and their rate against the measured peak."""
    s = ctx.settings
    cfg = get_preset(s.train_presets[0])
    state, (sur, _), _, stage_fns = stage_programs(cfg, batch=s.train_batch, train=True)
    rows, x = [], (sur,)
    for i, (name, fn) in enumerate(stage_fns):
        args = (state, *x)
        ctx.log(f"training stage {cfg.name} {name} ...")
        forward, compiled, _ = measure_program(
            ctx, lambda fn=fn, args=args: (compile_fn(fn, *args), args))
        out = compiled(*args)
        both, _, _ = measure_program(
            ctx, lambda fn=fn, args=args, i=i: (compile_fn(with_backward(fn, i > 0), *args),
                                                args))
        for direction, row in (("forward", forward), ("forward + backward", both)):
            rows.append({"preset": cfg.name, "batch": s.train_batch, "stage": name,
                         "direction": direction,
                         **{k: v for k, v in row.items() if not k.startswith("rss")}})
        rows[-1]["backward_ms"] = both["ms_median"] - forward["ms_median"]
        x = out if isinstance(out, tuple) else (out,)
    total = sum(r["ms_median"] for r in rows if r["direction"] == "forward + backward")
    for r in rows:
        if r["direction"] == "forward + backward":
            r["share"] = r["ms_median"] / total
    return {"rows": rows, "sum_ms": total}

