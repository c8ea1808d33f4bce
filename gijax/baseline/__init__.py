"""The classical sphere-sweep stereo baseline (RTSS): no learning, any rig and candidate list."""

from gijax.baseline.rtss import (RTSS_PRESETS, RTSSConfig, get_rtss_preset, preset_candidates,
                                 rtss_predict, rtss_predict_sample)

__all__ = ["RTSS_PRESETS", "RTSSConfig", "get_rtss_preset", "preset_candidates", "rtss_predict",
           "rtss_predict_sample"]
