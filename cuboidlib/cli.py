"""The ``cuboidlib`` command-line tool.

Each subcommand lives in a small ``_cmd_*`` function registered in :func:`build_parser`. Errors a
user can fix (bad paths, bad inputs) are printed as one readable line with a non-zero exit code;
``--traceback`` shows the full Python traceback instead.
"""

from __future__ import annotations

import argparse
import sys

from . import __version__


class UserError(Exception):
    """An error caused by the user's input: printed as one line, exit code 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cuboidlib",
        description="Cuboid shape abstraction via joint segmentation (Yang & Chen, SIGGRAPH 2021).",
    )
    parser.add_argument("--version", action="version", version=f"cuboidlib {__version__}")
    parser.add_argument("--traceback", action="store_true", help="show the full traceback on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (UserError, ValueError, FileNotFoundError, OSError) as exc:
        if args.traceback:
            raise
        print(f"cuboidlib {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"cuboidlib {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
