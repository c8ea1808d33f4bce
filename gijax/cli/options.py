"""Option types and help texts shared by several ``gijax`` commands (not a command itself)."""

from __future__ import annotations

import argparse
import json

CKPT_HELP = ("training run folder (config.json + checkpoints), inference bundle, or the name of "
             "a bundled model (see 'gijax models')")


def field_value(text: str) -> tuple[str, object]:
    """``FIELD=VALUE`` -> ``(FIELD, VALUE)``; VALUE is read as JSON, else kept as a string
    (``--override 'cost_hw=[8,32]'``, ``--override spherical_taps=tangent``)."""
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"expected FIELD=VALUE, found {text!r}")
    key, value = text.split("=", 1)
    try:
        return key.strip(), json.loads(value)
    except json.JSONDecodeError:
        return key.strip(), value
