"""The one message of a configuration value that cannot be used.

Every configuration class (``ModelConfig``, ``TrainConfig``, ``AdaptConfig``, ``LabelFree``,
``RTSSConfig``, ``MatchView``, ``DesignSpec``, ``RefineConfig``, ``LensDraw``) checks its fields
when it is made and raises :func:`bad_field`'s error, so a bad value reads the same wherever it
comes from: ``<Owner>.<field> must be <what it accepts>; found <the value>``. Documents on disk
(datasets, rig and calibration files) name their file and field instead (``gijax.data.format``,
``gijax.io.parsing``). Standard library only.
"""

from __future__ import annotations


def bad_field(owner: str, field: str, expected: str, found) -> ValueError:
    """The ValueError of ``owner.field`` holding ``found`` where ``expected`` was needed
    (``owner`` may carry an instance's name: ``ModelConfig 'G16-cpu'``)."""
    return ValueError(f"{owner}.{field} must be {expected}; found {found!r}")
