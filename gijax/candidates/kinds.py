"""Candidate lists by kind name: the lists a training config, ``gijax candidates`` and the
evaluation-time recomputation ask for by name, built from the closed forms and the rig-aware
solver."""

from __future__ import annotations

from gijax.candidates.closed_form import TRAIN_BASELINE, ev_candidates, gi_candidates
from gijax.candidates.rig_aware import rig_gi_candidates
from gijax.candidates.spacing import spacing_gi_candidates

KINDS = ("ev", "gi", "gi-closed", "gi-spacing")


def candidates_for(kind: str, n: int, rig=None, d_min=0.5, d_max=100.0, baseline=None, **opts):
    """Candidates of a kind: 'ev', 'gi' (rig-aware; needs ``rig``), 'gi-closed' or 'gi-spacing'.

    'gi-closed' uses ``baseline`` metres, default the training baseline behind the released
    lists (0.3095015413531889 m). 'gi-spacing' is the closed form with the rig's camera
    spacing as the baseline (needs ``rig``; the released list on the training rig).
    ``opts`` go to :func:`rig_gi_candidates`.
    """
    if kind == "ev":
        return ev_candidates(n, d_min, d_max)
    if kind == "gi-closed":
        return gi_candidates(n, d_min, d_max, TRAIN_BASELINE if baseline is None else baseline)
    if kind in ("gi", "gi-spacing") and rig is None:
        raise ValueError(f"kind={kind!r} needs a rig; found rig=None "
                         "(use kind='gi-closed' for the closed form with a given baseline)")
    if kind == "gi-spacing":
        return spacing_gi_candidates(rig, n, d_min, d_max)
    if kind == "gi":
        return rig_gi_candidates(rig, n, d_min, d_max, **opts)
    raise ValueError(f"kind must be one of {KINDS}; found kind={kind!r}")


RECOMPUTED = {"rig": "gi", "spacing": "gi-spacing", "ev": "ev"}
"""Evaluation-time candidate specs (``--candidates`` of eval and predict) -> candidate kind:
'rig' the rig-aware GI list, 'spacing' the closed form at the rig's camera spacing, 'ev' EV."""


def recomputed_candidates(spec: str, n: int, rig, d_min=0.5, d_max=100.0):
    """The list for an evaluation spec in :data:`RECOMPUTED` (whatever the training kind: the
    paper recomputes GI candidates for a new rig for EV-trained models too, Table II, E16)."""
    if spec not in RECOMPUTED:
        raise ValueError(f"candidate spec must be one of {sorted(RECOMPUTED)}; found {spec!r}")
    return candidates_for(RECOMPUTED[spec], n, rig=rig, d_min=d_min, d_max=d_max)
