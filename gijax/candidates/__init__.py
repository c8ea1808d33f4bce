"""Distance candidates: evenly spaced (EV), closed-form GI, rig-aware GI and their uniformity.

All lists are 1-D ascending distances in metres from ``d_min`` to ``d_max`` (inclusive).
"""

from __future__ import annotations

from gijax.candidates.closed_form import (TRAIN_BASELINE, closed_form_steps, ev_candidates,
                                          gi_candidates)
from gijax.candidates.rig_aware import (DEFAULT_PANO, RigTerms, cumulative_displacement,
                                        effective_baseline, fit_closed_form_baseline,
                                        rig_gi_candidates, rig_terms, solve_equal_steps)
from gijax.candidates.uniformity import (closed_form_uniformity, step_uniformity,
                                         summarize_steps)

KINDS = ("ev", "gi", "gi-closed")


def candidates_for(kind: str, n: int, rig=None, d_min=0.5, d_max=100.0, baseline=None, **opts):
    """Candidates of a kind: 'ev', 'gi' (rig-aware; needs ``rig``) or 'gi-closed'.

    'gi-closed' uses ``baseline`` metres, default the training baseline behind the released
    lists (0.3095015413531889 m). ``opts`` go to :func:`rig_gi_candidates`.
    """
    if kind == "ev":
        return ev_candidates(n, d_min, d_max)
    if kind == "gi-closed":
        return gi_candidates(n, d_min, d_max, TRAIN_BASELINE if baseline is None else baseline)
    if kind == "gi":
        if rig is None:
            raise ValueError("kind='gi' (rig-aware) needs a rig; found rig=None "
                             "(use kind='gi-closed' for the closed form)")
        return rig_gi_candidates(rig, n, d_min, d_max, **opts)
    raise ValueError(f"kind must be one of {KINDS}; found kind={kind!r}")


__all__ = [
    "KINDS", "TRAIN_BASELINE", "DEFAULT_PANO", "RigTerms", "candidates_for", "closed_form_steps",
    "closed_form_uniformity", "cumulative_displacement", "effective_baseline", "ev_candidates",
    "fit_closed_form_baseline", "gi_candidates", "rig_gi_candidates", "rig_terms",
    "solve_equal_steps", "step_uniformity", "summarize_steps",
]
