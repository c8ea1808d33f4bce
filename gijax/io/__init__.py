"""File I/O at the edge of the functional core: rig files (:mod:`gijax.io.rigfile`, the gijax
YAML format), calibration import (:mod:`gijax.io.kalibr`, :mod:`gijax.io.basalt`), per-camera
rig masks and the warning for rigs used without them (:mod:`gijax.io.masks`), the folder lock of
every writer (:mod:`gijax.io.lock`), and output path checks and atomic writes
(:mod:`gijax.io.paths`)."""

__all__ = ["load_rig", "save_rig"]


def __getattr__(name: str):
    # Rig files need the camera models and so JAX; paths and lock are used by writers that need
    # neither (colour maps, reports), so importing the package must not pull the geometry in.
    if name in __all__:
        from gijax.io import rigfile

        return getattr(rigfile, name)
    raise AttributeError(f"module 'gijax.io' has no attribute {name!r}")
