"""The whole benchmark suite (same as ``gijax bench``): prints the tables and writes
bench.json, bench.md and scaling.png to ``--out``.

  python benchmarks/run_suite.py --suite quick --out benchmarks/out/suite-cpu      # ~4 min, 2 cores
  python benchmarks/run_suite.py --suite full --device gpu --out benchmarks/out/suite-gpu
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from gijax.bench.suite import add_arguments, run_from_args  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    parser.set_defaults(out=os.path.join("benchmarks", "out", "suite"))
    return run_from_args(parser.parse_args(argv))


if __name__ == "__main__":
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())
