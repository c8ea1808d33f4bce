"""The rig-aware GI candidate solver and its gradient with respect to the camera positions."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from gijax.bench.cases.context import Context, measure_program
from gijax.bench.cost import compile_fn
from gijax.geometry.layouts import builtin_rig


def candidates(ctx: Context) -> dict:
    """Rig-aware GI candidate solve and the gradient of the list w.r.t. the camera positions."""
    from gijax.candidates import rig_gi_candidates
    from gijax.candidates.rig_aware import as_float_rig

    rows = []
    for rig_name in ctx.settings.candidate_rigs:
        rig = as_float_rig(builtin_rig(rig_name))
        for n in ctx.settings.candidate_counts:
            ctx.log(f"candidates {rig_name} n={n} ...")

            def solve(t, rig=rig, n=n):
                return rig_gi_candidates(rig.replace(translations=t), n)

            def loss(t, solve=solve):
                return jnp.sum(jnp.log(solve(t)))

            t = rig.translations
            row = {"rig": rig_name, "cameras": rig.num_cameras, "n": n}
            for what, fn in (("solve", solve), ("grad", jax.grad(loss))):
                r, _, _ = measure_program(ctx, lambda fn=fn: (compile_fn(fn, t), (t,)))
                row.update({f"{what}_{k}": v for k, v in r.items()
                            if k in ("compile_s", "ms_median", "ms_iqr", "ms_min", "gflop",
                                     "xla_peak_mib")})
            rows.append(row)
    return {"rows": rows}
