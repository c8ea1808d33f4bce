"""File I/O at the edge of the functional core: rig files and calibration import, the folder
lock of every writer (:mod:`gijax.io.lock`) and output path checks (:mod:`gijax.io.paths`)."""

from gijax.io.rigfile import load_rig, save_rig

__all__ = ["load_rig", "save_rig"]
