"""One optimiser step (forward, backward, Adam) of a preset on one device."""

from __future__ import annotations

import time

import jax
import numpy as np

from gijax.bench.cases.context import Context, program_row, timing_row
from gijax.bench.memory import CaseMemory
from gijax.bench.rigs import network_inputs, network_rig
from gijax.bench.timing import time_call
from gijax.geometry.layouts import builtin_rig


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
