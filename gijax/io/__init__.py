"""File I/O at the edge of the functional core: rig files and calibration import."""

from gijax.io.rigfile import load_rig, save_rig

__all__ = ["load_rig", "save_rig"]
