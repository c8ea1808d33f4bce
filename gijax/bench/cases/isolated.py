"""Every preset of the suite in fresh processes (:mod:`gijax.bench.isolated`): JAX whole forward
and stages, the exported file in onnxruntime under each memory profile, peak memory per
process."""

from __future__ import annotations

from gijax.bench.cases.context import Context


def isolated(ctx: Context) -> dict:
    from gijax.bench.isolated import measure_presets

    if ctx.device.platform != "cpu":
        ctx.log("isolated: measures CPU processes; skipped on this device")
        return {"rows": [], "skipped": "CPU only"}
    rows = measure_presets(ctx.settings.isolated_presets, reps=ctx.settings.reps, log=ctx.log)
    return {"rows": rows}
