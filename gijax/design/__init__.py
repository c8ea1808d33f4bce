"""Differentiable rig design: an objective for a camera layout, constraints, and its search.

See docs/design.md. The objective (:func:`objective_terms`) is the predicted inverse-distance
error over the panorama from the step resolution of the layout's own rig-aware GI candidates,
with soft (sigmoid) visibility so that positions and orientations get gradients.
"""

from gijax.design.constraints import (constraint_report, is_feasible, penalty, project,
                                      violations)
from gijax.design.objective import (at_least_two, camera_counts, design_camera, free_layout,
                                    layout_pose, objective, objective_terms, occluder_margin)
from gijax.design.optimize import (DesignResult, batch_report, evaluate_layouts, grid_points,
                                   grid_search, index_layout, layout_rig, optimize_layout,
                                   random_layouts, random_search, regular_layout, stack_layouts,
                                   terms_to_python, total_loss)
from gijax.design.spec import DesignSpec, Layout, make_layout

__all__ = [
    "DesignResult", "DesignSpec", "Layout", "at_least_two", "batch_report", "camera_counts",
    "design_camera", "constraint_report", "evaluate_layouts", "free_layout",
    "grid_points", "grid_search", "index_layout", "is_feasible", "layout_pose", "layout_rig",
    "make_layout", "objective", "objective_terms", "occluder_margin", "optimize_layout",
    "penalty", "project", "random_layouts", "random_search", "regular_layout", "stack_layouts",
    "terms_to_python", "total_loss", "violations",
]
