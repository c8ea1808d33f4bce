"""Sphere sweep: per-camera surrogate images, sweep grids and wrapped sampling."""

from gijax.sweep.grid import sweep_grid
from gijax.sweep.sample import sample_map, sample_sweep, sample_wrapped
from gijax.sweep.surrogate import surrogate_images

__all__ = ["sweep_grid", "sample_map", "sample_sweep", "sample_wrapped", "surrogate_images"]
