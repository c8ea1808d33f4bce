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


PANORAMA_HELP = (
    "part of the sphere the panorama covers: 'hemisphere' around the panorama pole (the paper's), "
    "'sphere', or 'auto' (default): the hemisphere when every camera looks within 60 deg of the "
    "rig's panorama pole, else the full sphere with the pole on the rig's up axis (the choice and "
    "its reason are printed)")
UP_HELP = ("the panorama's pole (top row) in the rig frame: x, y, z with an optional sign (e.g. "
           "-y) or 'a,b,c'; longitude 0 (the middle column) then faces camera 0. Default: the "
           "rig file's panorama frame, or the automatic choice of --panorama auto")
SIZE_HELP = ("panorama size HxW (rows x columns); default: the paper's angular resolution, "
             "{default} for the hemisphere and twice the rows for the sphere")


def add_panorama_options(parser, default_hw: str, size: bool = True) -> None:
    """--panorama, --up and (with ``size``) --panorama-size, with help naming ``default_hw``
    (e.g. '160x640')."""
    g = parser.add_argument_group(
        "panorama", "Equirectangular output: row 0 is the pole (the top), longitude grows to the "
        "right as seen from the centre (the common layout), 0 deg in the middle column.")
    g.add_argument("--panorama", choices=("auto", "hemisphere", "sphere"), default="auto",
                   help=PANORAMA_HELP)
    g.add_argument("--up", metavar="AXIS", help=UP_HELP)
    if size:
        g.add_argument("--panorama-size", metavar="HxW",
                       help=SIZE_HELP.format(default=default_hw))


def parse_size(text: str, what: str = "--panorama-size") -> tuple[int, int]:
    """``'HxW'`` -> (H, W); ValueError naming the option and the expected form."""
    parts = str(text).lower().split("x")
    try:
        h, w = (int(p) for p in parts)
    except ValueError:
        raise ValueError(f"{what} {text!r}: expected HxW, two positive integers (e.g. "
                         f"160x640)") from None
    if h <= 0 or w <= 0:
        raise ValueError(f"{what} {text!r}: expected two positive integers")
    return h, w


def panorama_from_args(args, rig, hemisphere_hw, log=print, size=None):
    """The rig with the chosen panorama frame and the output :class:`Panorama` from --panorama,
    --up and --panorama-size (or ``size``, (H, W), when given); ``hemisphere_hw`` is the default
    hemisphere size (the sphere gets twice its rows). The choice is reported through ``log``."""
    from gijax.geometry.panorama import Panorama
    from gijax.geometry.panorama_frame import choose_panorama, describe_choice, \
        with_panorama_rotation

    choice = choose_panorama(rig, getattr(args, "panorama", "auto"), getattr(args, "up", None))
    rig = with_panorama_rotation(rig, choice.rotation)
    pano = choice.panorama(hemisphere_hw)
    if size is None and getattr(args, "panorama_size", None):
        size = parse_size(args.panorama_size)
    if size is not None:
        pano = Panorama(int(size[0]), int(size[1]), pano.lat_min, pano.lat_max)
    if log is not None:
        log(describe_choice(choice, pano))
    return rig, pano
