"""Sphere sweep: per-camera surrogate images, sweep grids and wrapped sampling, and the grid
pytrees the network runs on (:mod:`gijax.sweep.grids`)."""

from gijax.sweep.grid import sweep_grid
from gijax.sweep.grids import (SurrogateMaps, SweepGrids, fisheye_surrogates, surrogate_resampling,
                               sweep_grids)
from gijax.sweep.sample import sample_map, sample_sweep, sample_wrapped
from gijax.sweep.surrogate import surrogate_images

__all__ = ["SurrogateMaps", "SweepGrids", "fisheye_surrogates", "sample_map", "sample_sweep",
           "sample_wrapped", "surrogate_images", "surrogate_resampling", "sweep_grid",
           "sweep_grids"]
