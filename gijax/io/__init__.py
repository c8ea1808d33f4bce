"""File I/O at the edge of the functional core, the owner of every on-disk format: rig files
(:mod:`gijax.io.rigfile`, the gijax YAML format), calibration import (:mod:`gijax.io.kalibr`,
:mod:`gijax.io.basalt`), text documents read with errors naming the file
(:mod:`gijax.io.text`), the one mask reader, per-camera rig masks and the warning for rigs used
without them (:mod:`gijax.io.masks`), PNG files read exactly (:mod:`gijax.io.png`), TensorBoard
event files (:mod:`gijax.io.events`), the folder lock of every writer (:mod:`gijax.io.lock`),
and output path checks and the one atomic write with its JSON, NPY, PNG and figure writers
(:mod:`gijax.io.paths`)."""

__all__ = ["load_rig", "save_rig"]


def __getattr__(name: str):
    # Rig files need the camera models and so JAX; paths and lock are used by writers that need
    # neither (colour maps, reports), so importing the package must not pull the geometry in.
    if name in __all__:
        from gijax.io import rigfile

        return getattr(rigfile, name)
    raise AttributeError(f"module 'gijax.io' has no attribute {name!r}")
