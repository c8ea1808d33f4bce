"""Calibration refinement from unlabeled images (:mod:`gijax.calibrate.refine`)."""

from gijax.calibrate.refine import (RefineConfig, RefineResult, align_gauge, apply_calibration,
                                    gauge_aligned_errors, pose_change, refine_rig,
                                    refinement_loss)

__all__ = ["RefineConfig", "RefineResult", "align_gauge", "apply_calibration",
           "gauge_aligned_errors", "pose_change", "refine_rig", "refinement_loss"]
