"""Distance candidates: evenly spaced (EV), closed-form GI, rig-aware GI and their uniformity.

All lists are 1-D ascending distances in metres from ``d_min`` to ``d_max`` (inclusive). Every
function here is traceable (jit, vmap, grad) with the count, kinds and panoramas static, except
:func:`check_candidates`, the eager check of a concrete list (see
:mod:`gijax.candidates.validation` for what is checked where).
"""

from __future__ import annotations

from gijax.candidates.closed_form import (TRAIN_BASELINE, closed_form_steps, ev_candidates,
                                          gi_candidates)
from gijax.candidates.kinds import KINDS, RECOMPUTED, candidates_for, recomputed_candidates
from gijax.candidates.rig_aware import (DEFAULT_PANO, MEASURE_UNITS, RigTerms,
                                        cumulative_displacement, effective_baseline,
                                        fit_closed_form_baseline, rig_gi_candidates, rig_terms,
                                        solve_equal_steps)
from gijax.candidates.parametrisation import candidates_from_logits, logits_from_candidates
from gijax.candidates.spacing import camera_spacing, spacing_gi_candidates
from gijax.candidates.uniformity import step_uniformity, summarize_steps
from gijax.candidates.validation import check_candidates, guard_candidates

__all__ = [
    "DEFAULT_PANO", "KINDS", "MEASURE_UNITS", "RECOMPUTED", "TRAIN_BASELINE", "RigTerms",
    "camera_spacing", "candidates_for", "candidates_from_logits", "check_candidates",
    "closed_form_steps", "cumulative_displacement", "effective_baseline", "ev_candidates",
    "fit_closed_form_baseline", "gi_candidates", "guard_candidates", "logits_from_candidates",
    "recomputed_candidates", "rig_gi_candidates", "rig_terms", "solve_equal_steps",
    "spacing_gi_candidates", "step_uniformity", "summarize_steps",
]
