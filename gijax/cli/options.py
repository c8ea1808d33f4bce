"""Option types and help texts shared by several ``gijax`` commands (not a command itself)."""

from __future__ import annotations

import argparse
import json

CKPT_HELP = ("training run folder (config.json + checkpoints), inference bundle, resume pack "
             "(pack.json: the network at the pack's step), or the name of a bundled model (see "
             "'gijax models')")


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


# Named axes accepted for an up direction, in the rig frame.
UP_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def parse_up(text: str):
    """``--up`` -> a unit rig-frame vector (NumPy float64 (3,)): an axis name (``x``, ``-y``,
    ``+z``) or three numbers ``'a,b,c'``. ValueError naming the accepted forms otherwise."""
    import numpy as np

    t = str(text).strip().lower()
    sign = -1.0 if t.startswith("-") else 1.0
    name = t.lstrip("+-")
    if name in UP_AXES:
        return sign * np.asarray(UP_AXES[name])
    try:
        v = np.asarray([float(p) for p in t.split(",")], np.float64)
    except ValueError:
        v = np.zeros(0)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) < 1e-9:
        raise ValueError(f"up axis {text!r}: expected x, y, z with an optional sign (e.g. -y) or "
                         f"three numbers 'a,b,c' (a non-zero rig-frame vector)")
    return v / np.linalg.norm(v)


def panorama_from_args(args, rig, hemisphere_hw, log=print, size=None):
    """The rig with the chosen panorama frame and the output :class:`Panorama` from --panorama,
    --up and --panorama-size (or ``size``, (H, W), when given); ``hemisphere_hw`` is the default
    hemisphere size (the sphere gets twice its rows). The choice is reported through ``log``."""
    from gijax.geometry.panorama import Panorama
    from gijax.geometry.panorama_frame import choose_panorama, describe_choice, \
        with_panorama_rotation

    up = getattr(args, "up", None)
    choice = choose_panorama(rig, getattr(args, "panorama", "auto"),
                             None if up is None else parse_up(up))
    rig = with_panorama_rotation(rig, choice.rotation)
    pano = choice.panorama(hemisphere_hw)
    if size is None and getattr(args, "panorama_size", None):
        size = parse_size(args.panorama_size)
    if size is not None:
        pano = Panorama(int(size[0]), int(size[1]), pano.lat_min, pano.lat_max)
    if log is not None:
        log(describe_choice(choice, pano))
    return rig, pano


# ------------------------------------------------------------------------- help formatting

class _DefaultsOnce(argparse.HelpFormatter):
    """Appends ``(default: X)`` to an option's help once: not when the help already states its
    default, not for a required option (it has none), not for a flag or an unset value (None)."""

    def _get_help_string(self, action):
        text = action.help or ""
        if ("default" in text.lower() or action.required or action.default is None
                or action.default is argparse.SUPPRESS or isinstance(action.default, bool)
                or not action.option_strings or action.default == []):
            return text
        return f"{text} (default: %(default)s)"


class HelpFormatter(_DefaultsOnce):
    """Every command's formatter: the description wrapped, each option's default once."""


class RawHelpFormatter(_DefaultsOnce, argparse.RawDescriptionHelpFormatter):
    """For commands whose description is laid out by hand (lists, examples)."""


# ------------------------------------------------------------------------------- sizes

def parse_hw(text: str, what: str = "size") -> tuple[int, int]:
    """``'HxW'`` (rows x columns) -> ``(H, W)``; ArgumentTypeError naming ``what`` and the
    order expected (the type of every size option of the command line)."""
    try:
        return parse_size(text, what)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def hw_type(what: str):
    """An argparse ``type`` reading HxW for option ``what``."""
    return lambda text: parse_hw(text, what)


def wh_type(what: str, new: str):
    """The type of a kept width-first option (``what``, superseded by ``new``): ``'WxH'`` ->
    ``(H, W)``, so that every size leaves the parser rows first."""

    def parse(text: str) -> tuple[int, int]:
        try:
            w, h = parse_size(text, what)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{what} {text!r}: expected WxH, width x height (e.g. 640x160); {new} takes "
                f"HxW, rows x columns") from None
        return h, w

    return parse


# --------------------------------------------------------------------------------- rigs

def builtin_rig_names() -> list[str]:
    """The built-in rig layouts' names, from the library (for help texts)."""
    from gijax.geometry.layouts import BUILTIN_LAYOUTS

    return sorted(BUILTIN_LAYOUTS)


def rig_help(default: str | None = None) -> str:
    """The one description of a rig argument; ``default`` says what a missing --rig means."""
    text = (f"built-in rig name ({', '.join(builtin_rig_names())}; see 'gijax rig list') or a "
            f"rig file: gijax YAML, Kalibr / TartanCalib camchain.yaml or basalt calibration "
            f"JSON")
    return f"{text} (default: {default})" if default else text


def add_rig_option(parser, required: bool = False, default: str | None = None,
                   default_help: str | None = None) -> None:
    """``--rig NAME|FILE``: ``required``, or optional with ``default`` (a built-in name) or,
    when None, what ``default_help`` says the command uses instead (e.g. the dataset's rig)."""
    parser.add_argument("--rig", required=required, default=default, metavar="NAME|FILE",
                        help=rig_help(None if required else (default or default_help)))


# --------------------------------------------------------------------------- candidates

def add_candidates_option(parser, default: str | None, default_help: str,
                          flag: str = "--candidates", what: str = "distance candidates") -> None:
    """The one ``--candidates`` grammar (:mod:`gijax.candidates.spec`); ``default_help`` says
    what a missing spec means for this command."""
    from gijax.candidates.spec import HELP, METAVAR

    parser.add_argument(flag, default=default, metavar=METAVAR,
                        help=f"{what}: {HELP}. Default: {default_help}")


def add_estimate_option(parser) -> None:
    """``--estimate mean|mode``: how a learned model's distance is read from its probabilities
    (:mod:`gijax.nn.regressor`); without it, the model's own configuration decides."""
    from gijax.nn.regressor import ESTIMATES

    parser.add_argument("--estimate", choices=ESTIMATES, default=None,
                        help="how the learned model reads distance from its probabilities over "
                             "the candidates: 'mean' (the paper's soft-argmax, the expectation "
                             "over all of them) or 'mode' (the expectation within the "
                             "configuration's mode_window, normally 2, of the most probable "
                             "candidate, read at its mode_pick: at an occlusion edge one "
                             "surface instead of a "
                             "distance between two); the same weights either way. Default: "
                             "the model's own (its configuration's 'estimate')")


# ------------------------------------------------------------------------------- methods

METHODS = ("learned", "rtss")
METHOD_ALIASES = {"net": "learned"}


def _method(text: str) -> str:
    return METHOD_ALIASES.get(text, text)


def add_method_option(parser, aliases: bool = False) -> None:
    """``--method learned|rtss``; with ``aliases`` the older spelling ``net`` is accepted for
    ``learned`` (command lines written for earlier releases)."""
    alias = " ('net' is accepted for 'learned')" if aliases else ""
    parser.add_argument("--method", type=_method if aliases else str, choices=METHODS,
                        default="learned",
                        help=f"'learned' (the trained network of --ckpt; default) or 'rtss' "
                             f"(the classical sphere-sweep baseline, no model){alias}")


def add_rtss_preset_option(parser) -> None:
    """``--rtss-preset NAME`` with the presets listed from the library."""
    from gijax.baseline.rtss import RTSS_PRESETS

    parser.add_argument("--rtss-preset", default="RS-E32", metavar="NAME",
                        help=f"RTSS configuration for --method rtss ({', '.join(RTSS_PRESETS)}; "
                             f"default RS-E32)")
