"""The one message of a value that cannot be used, in a configuration or in a file.

Every configuration class (``ModelConfig``, ``TrainConfig``, ``AdaptConfig``, ``LabelFree``,
``RTSSConfig``, ``MatchView``, ``DesignSpec``, ``RefineConfig``, ``LensDraw``) checks its fields
when it is made and raises :func:`bad_field`'s error, so a bad value reads the same wherever it
comes from: ``<Owner>.<field> must be <what it accepts>; found <the value>``. Every document
reader (datasets, rig and calibration files, resume packs) raises :func:`bad_document_field`'s,
the same sentence led by the file: ``<file>: field '<field>' must be <what it accepts>; found
<the value>``. Standard library only.
"""

from __future__ import annotations


class Found(str):
    """Text that a message shows as it is after 'found' (a description, not a value)."""

    def __repr__(self) -> str:
        return str(self)


# What a document holds in place of a field it lacks.
MISSING = Found("nothing (the field is missing)")


# JSON's words for the Python types a document's values are read as.
_KIND_WORDS = {"str": "a string", "list": "a list", "dict": "a JSON object", "int": "an integer",
               "float": "a number", "bool": "true or false", "NoneType": "null"}


def kind_name(kind: type | tuple) -> str:
    """What a message says a field must be for the type (or types) ``kind``."""
    kinds = kind if isinstance(kind, tuple) else (kind,)
    return " or ".join(_KIND_WORDS.get(k.__name__, f"a {k.__name__}") for k in kinds)


def kind_of(value) -> Found:
    """The type of ``value`` as a message shows it (for values too long to print)."""
    return Found(kind_name(type(value)))


def bad_field(owner: str, field: str, expected: str, found) -> ValueError:
    """The ValueError of ``owner.field`` holding ``found`` where ``expected`` was needed
    (``owner`` may carry an instance's name: ``ModelConfig 'G16-cpu'``)."""
    return ValueError(f"{owner}.{field} must be {expected}; found {found!r}")


def bad_document_field(document, field: str, expected: str, found, *,
                       within: str | None = None) -> ValueError:
    """The ValueError of field ``field`` of the file ``document`` holding ``found`` (a value,
    :data:`MISSING`, or a :class:`Found` description) where ``expected`` was needed;
    ``within`` names the part of the document (``camera 'cam1'``)."""
    where = f"{document}: {within}" if within else f"{document}"
    return ValueError(f"{where}: field {field!r} must be {expected}; found {found!r}")
