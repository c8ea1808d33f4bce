"""``gijax data check DIR``: verify every file of a dataset folder before using it."""

from __future__ import annotations

import sys

from gijax.cli.options import HelpFormatter

MAX_LISTED = 20


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "data", help="dataset folder tools (check)",
        description="Tools for gijax dataset folders (docs/data.md).")
    sub = p.add_subparsers(dest="data_command", metavar="ACTION", required=True)
    c = sub.add_parser(
        "check", help="verify every file of a dataset (decodes, sizes, value ranges, completeness)",
        description=(
            "Read every file a dataset lists: each RGB, distance and mask PNG must be whole "
            "(chunk CRCs), decode with the camera's size and channel count, and distances must "
            "be finite and >= 0 (0 marks a label hole). Also reports whether the dataset holds "
            "all the samples its manifest requests (an interrupted 'gijax render' leaves fewer), whether a writer "
            "holds it now, and files no row lists. Exits 1 on any damaged file or when the "
            "dataset is incomplete (unless --allow-partial). 'gijax train' runs the same check "
            "on its data before it starts."),
        formatter_class=HelpFormatter)
    c.add_argument("dir", metavar="DIR", help="dataset folder (the one holding manifest.json)")
    c.add_argument("--allow-partial", action="store_true",
                   help="an incomplete dataset (fewer samples than requested) is not an error")
    c.add_argument("--no-progress", action="store_true", help="no progress bar")
    c.set_defaults(func=run)


def run(args) -> int:
    from gijax.data.check import check_with_progress

    result = check_with_progress(args.dir, progress=not args.no_progress)
    for line in result.problems[:MAX_LISTED]:
        print(f"  problem: {line}")
    if len(result.problems) > MAX_LISTED:
        print(f"  ... and {len(result.problems) - MAX_LISTED} more problem(s)")
    for line in result.notes[:MAX_LISTED]:
        print(f"  note: {line}")
    if len(result.notes) > MAX_LISTED:
        print(f"  ... and {len(result.notes) - MAX_LISTED} more note(s)")
    print(result.summary())
    if result.problems or (not result.complete and not args.allow_partial):
        why = (f"{len(result.problems)} damaged or missing file(s)" if result.problems else
               f"incomplete ({result.samples} of {result.requested} samples)")
        print(f"gijax data check: error: {args.dir}: {why}", file=sys.stderr)
        return 1
    return 0
