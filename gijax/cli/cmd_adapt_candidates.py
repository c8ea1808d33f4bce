"""``gijax adapt-candidates``: optimise a trained model's candidate list for a rig, the network
frozen (:func:`gijax.train.adapt.adapt_candidates`)."""

from __future__ import annotations

import shlex

HELP = "adapt a trained model's candidate list to a rig (network frozen)"
DESCRIPTION = """\
Optimise the distance candidates of a trained model for one rig by gradient descent, the
network's weights untouched. The list is parametrised so that every step stays valid (strictly
increasing, the starting list's ends kept: see docs/candidates.md, "Learned lists"), and it
starts from --init.

Losses (--loss): 'supervised' (smooth L1 on inverse distance against the labels of --data, a
gijax dataset rendered for the rig, e.g. by 'gijax render --rig R') or 'photometric' (no
labels: every predicted point is projected into the cameras and their colours compared, masks
respected; the labels of --data are ignored).

Writes --out (a JSON object whose 'candidates' list every candidate spec takes as a file)
and, beside it, OUT.adapt/ with the checkpoint, the loss curve (curve.csv, curve.png) and
record.json (the command). Running the same command again resumes. Evaluate the result on held-out scenes with
'gijax eval --candidates OUT'.
"""


def register(subparsers) -> None:
    from gijax.cli.options import (CKPT_HELP, RawHelpFormatter, add_candidates_option,
                                   add_rig_option)

    p = subparsers.add_parser(
        "adapt-candidates", help=HELP, formatter_class=RawHelpFormatter,
        description=DESCRIPTION)
    p.add_argument("--ckpt", required=True, metavar="PATH|NAME", help=CKPT_HELP)
    p.add_argument("--data", required=True, metavar="DIR",
                   help="dataset of the rig (gijax's layout or the release's, DIR@KEY)")
    add_rig_option(p, default_help="the dataset's rig")
    p.add_argument("--out", required=True, metavar="LIST.json", help="adapted list file")
    p.add_argument("--loss", choices=("supervised", "photometric"), default="supervised",
                   help="supervised (labels) or photometric (no labels); default supervised")
    add_candidates_option(p, "train", "'train', the model's training list", flag="--init",
                          what="starting list")
    p.add_argument("--steps", type=int, default=200, help="Adam steps (default 200)")
    p.add_argument("--lr", type=float, default=0.05,
                   help="Adam learning rate on the list's logits (default 0.05)")
    p.add_argument("--batch", type=int, default=4, help="samples per step (default 4)")
    p.add_argument("--seed", type=int, default=0, help="data order (default 0)")
    p.add_argument("--workers", type=int, default=2, help="data loader threads (default 2)")
    p.add_argument("--allow-partial", action="store_true",
                   help="accept a dataset holding fewer samples than its manifest requests")
    p.set_defaults(func=run)


def _command(args) -> str:
    """The command line that reproduces this run (recorded beside the list)."""
    parts = ["gijax", "adapt-candidates"]
    for key, value in sorted(vars(args).items()):
        if key in ("func", "command") or value is None or value is False:
            continue
        flag = "--" + key.replace("_", "-")
        parts += [flag] if value is True else [flag, shlex.quote(str(value))]
    return " ".join(parts)


def run(args) -> int:
    import numpy as np

    from gijax.candidates.spec import model_candidates
    from gijax.io.paths import check_output_file
    from gijax.model import model_panorama
    from gijax.store import load_model
    from gijax.train.adapt import AdaptConfig, adapt_candidates
    from gijax.train.sources import dataset_stream_factory, open_dataset
    from gijax.model import model_rig

    check_output_file(args.out, "--out")
    config = AdaptConfig(loss=args.loss, steps=args.steps, lr=args.lr, batch_size=args.batch,
                         seed=args.seed)
    model, mc, train_cand = load_model(args.ckpt)
    reader = open_dataset(args.data, "adaptation", args.allow_partial)
    rig = reader.rig
    if args.rig:
        from gijax.io.rigfile import load_rig

        # The labels fix the panorama frame: the dataset's, whatever the rig file says.
        rig = load_rig(args.rig).replace(panorama_rotation=reader.rig.panorama_rotation)
    want = model_panorama(mc)
    label = getattr(reader, "pano", None)
    if args.loss == "supervised" and label is not None and label.shape != want.shape:
        raise ValueError(f"{args.data}: labels are {label.height} x {label.width} panoramas but "
                         f"model {mc.name!r} outputs {want.height} x {want.width}; render the "
                         f"data at the model's size (gijax render --panorama-size "
                         f"{want.height}x{want.width} --scale {mc.image_scale:g})")
    initial, how = model_candidates(args.init, rig, mc, train=train_cand)
    print(f"model {mc.name}; rig {args.rig or 'of ' + str(args.data)}; start: {how}")
    make = dataset_stream_factory(reader, rig, config.batch_size, config.seed, mc.surrogate_hw,
                                  workers=args.workers, what="adaptation")
    record = {"command": _command(args), "model": str(args.ckpt), "data": str(args.data),
              "init": how}
    result = adapt_candidates(model, model_rig(rig), make, initial, config, args.out,
                              record=record, log=print)
    h = [x["loss"] for x in result.history]
    k = max(1, min(10, len(h) // 4))
    if h:
        print(f"{args.loss} loss: first {k} steps {np.mean(h[:k]):.4f}, last {k} steps "
              f"{np.mean(h[-k:]):.4f}")
    print("initial  " + " ".join(f"{c:.3f}" for c in result.initial))
    print("adapted  " + " ".join(f"{c:.3f}" for c in result.candidates))
    for kind, path in result.files.items():
        print(f"  {kind:6s} {path}")
    return 0
