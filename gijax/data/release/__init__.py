"""Datasets laid out as the paper's released training code expects them.

``layout`` names the files, keys and frames of such a folder; ``detection`` tells it from a
gijax dataset; ``frame_graph``, ``cameras``, ``file_lists`` and ``images`` read its documents,
camera models, file lists and image files; ``labels`` resamples the rig's distance images into
gijax's panorama; ``reader`` puts them together into samples.
"""

from gijax.data.release.detection import detect_layout, open_reader
from gijax.data.release.reader import ReleaseDatasetReader

__all__ = ["ReleaseDatasetReader", "detect_layout", "open_reader"]
