"""``gijax import-weights``: a released PyTorch checkpoint -> a gijax inference bundle."""

from __future__ import annotations

import argparse

from gijax.cli.options import field_value

HELP = "turn the authors' released checkpoint into a gijax bundle (--ckpt for predict/eval/export)"
DESCRIPTION = """\
Read a state dict of the authors' released network (castacks/mvs_gi) and write an inference
bundle that 'gijax predict --ckpt DIR' accepts (and so do eval and export).

SRC is a Lightning .ckpt, a PyTorch .pth / .pt (both need torch: pip install 'gijax[torch]')
or an .npz holding the state dict's arrays under the same names (or under 'sd/NAME').
--preset names the structure the weights belong to (G16V-released for the released ONNX model,
G16VV, G16, ...); --override changes a field of that preset, for weights trained at other sizes.
The release trained on BGR images: the bundle reverses the first conv's input channels, so it
takes RGB like every gijax model (--input-order rgb keeps the weights as they are). The
candidates stored in the checkpoint become the bundle's training candidates.

Every name that does not map, every missing entry and every shape mismatch is listed in one
error; nothing is written then.

example:
  gijax import-weights G16VV.ckpt --preset G16VV --out bundles/g16vv-released
  gijax predict --ckpt bundles/g16vv-released --rig paper-train --images c0.png c1.png c2.png --out pred
"""


def register(subparsers) -> None:
    p = subparsers.add_parser("import-weights", help=HELP, description=DESCRIPTION,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("src", metavar="SRC", help="release checkpoint (.ckpt, .pth, .pt or .npz)")
    p.add_argument("--preset", required=True, metavar="NAME",
                   help="gijax preset with the checkpoint's structure, e.g. G16V-released")
    p.add_argument("--out", required=True, metavar="DIR", help="bundle folder to write")
    p.add_argument("--override", action="append", type=field_value, default=[],
                   metavar="FIELD=VALUE", help="replace a preset field (JSON value), e.g. "
                   "surrogate_hw=[256,1024]; repeatable")
    p.add_argument("--input-order", choices=("bgr", "rgb"), default="bgr",
                   help="colour order the weights were trained on (default bgr, the release)")
    p.set_defaults(func=run)


def run(args) -> int:
    from gijax.store import load_bundle
    from gijax.train.import_release import import_release_weights

    out = import_release_weights(args.src, args.preset, args.out,
                                 overrides=dict(args.override), input_order=args.input_order)
    _, config, cand = load_bundle(out)
    print(f"wrote bundle {out}: model {config.name}, candidates "
          f"{', '.join(f'{c:.3g}' for c in cand.tolist())} m")
    return 0
