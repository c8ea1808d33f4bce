"""The classical sphere-sweep stereo baseline (RTSS): no learning, any rig and candidate list.

Every function of the pipeline is traceable (jit, vmap; grad where it is not piecewise
constant); the exceptions are :func:`get_rtss_preset` (settings by name) and
:func:`rtss_predict_sample` (NumPy outputs for one loaded sample).
"""

from gijax.baseline.rtss import (RTSS_PRESETS, RTSSConfig, get_rtss_preset, preset_candidates,
                                 rtss_predict, rtss_predict_sample, sphere_sweep)

__all__ = ["RTSS_PRESETS", "RTSSConfig", "get_rtss_preset", "preset_candidates", "rtss_predict",
           "rtss_predict_sample", "sphere_sweep"]
