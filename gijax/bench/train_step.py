"""A preset's compiled training step on a fixed in-memory batch, and its time.

Shared by ``benchmarks/bench_train.py`` (one preset per process, forced device counts) and the
design comparison (``experiments/design_comparison.py``), which times several designs in
alternating rounds in one process so that every design sees the same machine load.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from typing import Callable

import jax
import numpy as np


@dataclasses.dataclass
class TrainStepCase:
    """One compiled step: ``run()`` does one optimiser step (state kept inside)."""

    preset: str
    batch: int
    compile_s: float
    run: Callable[[], dict]


def train_step_case(preset: str, batch: int, overrides: dict | None = None) -> TrainStepCase:
    """The data-parallel training step of ``preset`` (forward, backward, Adam, volume or L1
    loss) over all local devices, on the training triangle rig at the network's image size
    and a fixed random batch; compiled and run once before it is returned."""
    from gijax.bench.rigs import network_inputs, network_rig
    from gijax.geometry.layouts import builtin_rig
    from gijax.model import create_model
    from gijax.train import step as S
    from gijax.train.config import TrainConfig

    cfg = TrainConfig(preset=preset, batch_size=batch, model_overrides=dict(overrides or {}))
    mc = cfg.model_config()
    rig = network_rig(builtin_rig("paper-train"), mc)
    if mc.cost_volume == "concat" and mc.num_cameras != rig.num_cameras:
        raise ValueError(f"the benchmark rig has {rig.num_cameras} cameras; {preset} needs "
                         f"{mc.num_cameras}")
    t0 = time.perf_counter()
    model = create_model(mc, 0)
    tdef, _, params, rest = S.split_model(model)
    tx = S.make_optimizer(cfg)
    mesh = S.make_mesh()
    holder = {"state": S.place_state(S.init_state(params, rest, tx), mesh)}
    step = S.jit_train_step(S.build_train_step(tdef, tx, mc.loss), mesh)
    sur, masks, cand = network_inputs(mc, rig.num_cameras, batch)
    h, w = mc.output_hw
    rng = np.random.default_rng(0)
    batch_np = {"surrogates": np.asarray(sur), "masks": np.asarray(masks),
                "distance": rng.uniform(0.5, 20, (batch, h, w)).astype(np.float32),
                "valid": np.ones((batch, h, w), bool)}

    def run() -> dict:
        holder["state"], out = step(holder["state"], S.place_batch(batch_np, mesh), rig, cand)
        return out

    jax.block_until_ready(run())
    return TrainStepCase(preset, batch, time.perf_counter() - t0, run)


def time_steps(case: TrainStepCase, steps: int) -> float:
    """Seconds per step over ``steps`` consecutive steps."""
    t0 = time.perf_counter()
    out = None
    for _ in range(steps):
        out = case.run()
    jax.block_until_ready(out)
    return (time.perf_counter() - t0) / steps


def alternating_step_seconds(cases: list[TrainStepCase], steps: int, rounds: int,
                             progress: Callable[[str], None] | None = None) -> dict:
    """``{preset: median seconds per step}`` over ``rounds`` rounds that time every case in
    turn (``steps`` steps each): a load that comes and goes falls on every case alike."""
    times: dict = {c.preset: [] for c in cases}
    for r in range(rounds):
        for c in cases:
            times[c.preset].append(time_steps(c, steps))
            if progress is not None:
                progress(f"round {r + 1}/{rounds} {c.preset}: {times[c.preset][-1]:.3f} s/step")
    return {k: statistics.median(v) for k, v in times.items()}
