"""The ``gijax`` command line: one subcommand per module in this package.

Each ``gijax/cli/cmd_*.py`` module defines ``register(subparsers)``, which adds its subcommand
and sets ``func`` (called with the parsed arguments, returning an exit code).
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import warnings


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gijax",
        description=(
            "Omnidirectional distance from multi-fisheye rigs with geometry-informed (GI) "
            "distance candidates. Run 'gijax demo' first; 'gijax COMMAND --help' explains each "
            "command."
        ),
    )
    from gijax import __version__

    parser.add_argument("--version", action="version", version=f"gijax {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    import gijax.cli as pkg

    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
        if info.name.startswith("cmd_"):
            importlib.import_module(f"gijax.cli.{info.name}").register(sub)
    return parser


def _warning_printer(command: str):
    """``warnings.showwarning`` for the command line: ``gijax CMD: warning: ...`` without the
    source file and line that Python's default adds (they mean nothing to a user)."""

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"gijax {command}: warning: {message}", file=file or sys.stderr)

    return show


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    args.argv = argv     # the command line as given, for the records of long jobs
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from gijax.io.lock import FolderLockedError

    try:
        with warnings.catch_warnings():
            warnings.showwarning = _warning_printer(args.command)
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        # Ctrl-C: one line saying what was kept (a command that keeps something says what in
        # args.interrupted_keeps), not Python's traceback.
        kept = getattr(args, "interrupted_keeps", None)
        print(f"gijax {args.command}: interrupted" + (f"; {kept}" if kept else ""),
              file=sys.stderr)
        return 130
    except (ValueError, FileNotFoundError, FolderLockedError) as exc:
        print(f"gijax {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        # A path of the wrong kind or without permission, found by the operating system: one
        # line naming the path, not a traceback.
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"gijax {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1


def run() -> None:
    """The ``gijax`` program: :func:`main` on this process's arguments, in a process whose
    allocator asks for transparent huge pages (:func:`gijax.host_memory.use_huge_pages`)."""
    from gijax.host_memory import use_huge_pages

    use_huge_pages()
    sys.exit(main())


if __name__ == "__main__":
    run()
