"""gijax against its PyTorch twin in fresh processes (:mod:`gijax.bench.torch_peer`):
inference and training step, alternating frameworks, the same threads, peak memory per
process."""

from __future__ import annotations

from gijax.bench.cases.context import Context


def torch_peer(ctx: Context) -> dict:
    from gijax.bench.torch_peer import measure_peers

    if ctx.device.platform != "cpu":
        ctx.log("torch-peer: times CPU processes; skipped on this device")
        return {"rows": [], "skipped": "CPU only"}
    s = ctx.settings
    return measure_peers(s.torch_presets, s.torch_batches, s.torch_modes, s.torch_rounds,
                         reps=s.reps, warmup=s.warmup, threads=s.torch_threads,
                         torch_python=s.torch_python, log=ctx.log)
