"""The exported file in fp32, fp16 (the precision plan) and int8 (QDQ) run by onnxruntime on
the CPU, each in a fresh process (:func:`gijax.bench.isolated.measure_precisions`): seconds per
forward, peak resident set and file size, side by side per preset."""

from __future__ import annotations

from gijax.bench.cases.context import Context


def precision(ctx: Context) -> dict:
    from gijax.bench.isolated import measure_precisions

    if ctx.device.platform != "cpu":
        ctx.log("precision: measures onnxruntime CPU processes; skipped on this device")
        return {"rows": [], "skipped": "CPU only"}
    s = ctx.settings
    rows = measure_precisions(s.precision_presets, reps=s.reps,
                              calibration=s.precision_calibration, log=ctx.log)
    return {"rows": rows, "calibration_scenes": s.precision_calibration}
